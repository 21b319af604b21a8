/// \file test_point_to_plane_refinement.cpp
/// \brief Point-to-plane refinement: convergence on a synthetic structured scene from a
/// 0.5 m / 5 deg perturbation, failure paths, and accuracy on the two real scan pairs.

#include "test_data.h"

#include <Eigen/Eigenvalues>
#include <chrono>
#include <fstream>
#include <gtest/gtest.h>
#include <limits>
#include <map>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/registration/point_to_plane_refinement.h>
#include <random>
#include <tuple>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_point_to_plane_refinement {

namespace {

using pcl_rast_test::readMatrix4;

using pcl::rast::PointToPlaneParams;
using pcl::rast::PointToPlaneTarget;
using pcl::rast::PointVector;

Eigen::Isometry3d
makeTransform(double roll_deg, double pitch_deg, double yaw_deg, const Eigen::Vector3d& t)
{
  const double d = M_PI / 180.0;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(yaw_deg * d, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch_deg * d, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll_deg * d, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = t;
  return T;
}

double
translationError(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b)
{
  return (a.inverse() * b).translation().norm();
}

double
rotationErrorDeg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b)
{
  return Eigen::AngleAxisd((a.inverse() * b).rotation()).angle() * 180.0 / M_PI;
}

/// A street-like scene in the world frame: ground, two facades with different setbacks,
/// a back wall, and boxes (parked cars, kiosks), sampled uniformly with 1 cm noise.
PointVector
sampleScene(std::uint32_t seed, int points_per_m2_x10 = 30)
{
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 0.01);
  PointVector points;
  // Axis-aligned rectangle: fixed axis `axis` at `value`, spanning [lo, hi] on the others.
  auto rectangle = [&](int axis, double value, Eigen::Vector3d lo, Eigen::Vector3d hi) {
    lo[axis] = hi[axis] = value;
    Eigen::Vector3d size = hi - lo;
    size[axis] = 1.0;
    const int n = static_cast<int>(size.prod() * points_per_m2_x10 / 10.0);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (int i = 0; i < n; ++i) {
      Eigen::Vector3d p;
      for (int a = 0; a < 3; ++a)
        p[a] = lo[a] + u(rng) * (hi[a] - lo[a]);
      points.push_back(p + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
    }
  };
  auto box = [&](const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
    for (int axis = 0; axis < 3; ++axis) {
      rectangle(axis, lo[axis], lo, hi);
      rectangle(axis, hi[axis], lo, hi);
    }
  };
  rectangle(2, 0.0, {-30, -12, 0}, {30, 12, 0});  // ground
  rectangle(1, 8.0, {-30, 8, 0}, {30, 8, 8});      // left facade
  rectangle(1, -10.0, {-30, -10, 0}, {30, -10, 6}); // right facade
  rectangle(0, 30.0, {30, -10, 0}, {30, 8, 5});    // back wall
  box({4, 4, 0}, {8.5, 6, 1.5});
  box({-12, -8, 0}, {-7.5, -6.2, 1.6});
  box({15, 2, 0}, {17, 4, 2.5});
  box({-20, 3, 0}, {-18, 6, 3});
  return points;
}

PointVector
transformed(const Eigen::Isometry3d& T, const PointVector& points)
{
  PointVector out;
  out.reserve(points.size());
  for (const auto& p : points)
    out.push_back(T * p);
  return out;
}

TEST(PointToPlaneRefinement, VoxelDownsampleKeepsOnePointPerVoxel)
{
  PointVector points{{0.1, 0.1, 0.1}, {0.2, 0.3, 0.4}, {1.1, 0.1, 0.1}, {-0.1, 0.1, 0.1},
                     {NAN, 0.0, 0.0}};
  const PointVector out = pcl::rast::voxelDownsample(points, 1.0);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_TRUE(out[0].isApprox(points[0]));
  EXPECT_EQ(pcl::rast::voxelDownsample(points, 0.0).size(), 4u);
}

class SyntheticScene : public ::testing::Test
{
protected:
  void
  SetUp() override
  {
    // Target scan = scene in the target frame; source scan = an independent sampling
    // of the same scene seen from the source frame.
    // 5 deg moves the far wall (30 m) by 2.6 m: widen the association radius.
    params_.max_correspondence_distance_m = 2.0;
    params_.max_iterations = 100;
    T_target_source_ = makeTransform(1.0, -0.5, 8.0, Eigen::Vector3d(1.2, -0.4, 0.05));
    target_points_ = sampleScene(1);
    source_points_ = transformed(T_target_source_.inverse(), sampleScene(2));
    target_.build(target_points_, params_);
    source_ = pcl::rast::voxelDownsample(source_points_, params_.source_voxel_size_m);
    PointToPlaneParams source_params = params_;
    source_params.target_voxel_size_m = params_.source_voxel_size_m;
    source_planes_.build(source_points_, source_params);
  }

  PointToPlaneParams params_;
  Eigen::Isometry3d T_target_source_;
  PointVector target_points_, source_points_, source_;
  PointToPlaneTarget target_, source_planes_; // source_planes_: prepared, with normals
};

TEST_F(SyntheticScene, ConvergesFromHalfMetreFiveDegreePerturbation)
{
  ASSERT_GT(target_.size(), 1000u);
  const Eigen::Isometry3d perturbations[] = {
      makeTransform(0, 0, 5, Eigen::Vector3d(0.5, 0, 0)),
      makeTransform(0, 0, -5, Eigen::Vector3d(-0.3, 0.4, 0)),
      makeTransform(3, 3, 3, Eigen::Vector3d(0.29, 0.29, 0.29)),
      makeTransform(-2, 4, -3, Eigen::Vector3d(0, -0.4, 0.3))};
  for (const auto& perturbation : perturbations) {
    const Eigen::Isometry3d guess = perturbation * T_target_source_;
    ASSERT_GT(translationError(guess, T_target_source_), 0.3);
    // Plane-to-plane (prepared source) and point-to-plane (plain points).
    for (const bool prepared : {true, false}) {
      const auto result =
          prepared ? pcl::rast::refinePointToPlane(source_planes_, target_, guess, params_)
                   : pcl::rast::refinePointToPlane(source_, target_, guess, params_);
      ASSERT_TRUE(result.success) << result.message;
      EXPECT_TRUE(result.converged) << result.message;
      // Point-to-plane on plain points: 1.2 cm (edge voxels of the boxes); plane-to-plane
      // stays within 1 cm.
      EXPECT_LT(translationError(result.T_target_source, T_target_source_),
                prepared ? 0.01 : 0.015)
          << result.message;
      EXPECT_LT(rotationErrorDeg(result.T_target_source, T_target_source_), 0.05)
          << result.message;
      EXPECT_LT(result.rmse_m, 0.03);
    }
  }
}

TEST_F(SyntheticScene, AllKernelsConvergeAndTheInverseToo)
{
  const Eigen::Isometry3d guess =
      makeTransform(0, 0, 4, Eigen::Vector3d(0.4, 0.2, 0)) * T_target_source_;
  for (const auto kernel : {pcl::rast::RobustKernel::kNone, pcl::rast::RobustKernel::kHuber,
                            pcl::rast::RobustKernel::kTukey}) {
    PointToPlaneParams params = params_;
    params.kernel = kernel;
    const auto result = pcl::rast::refinePointToPlane(source_planes_, target_, guess, params);
    ASSERT_TRUE(result.success) << result.message;
    EXPECT_LT(translationError(result.T_target_source, T_target_source_), 0.02)
        << "kernel " << static_cast<int>(kernel) << ": " << result.message;
  }
  // Swap the roles: register the target scan to the source scan.
  PointToPlaneTarget source_as_target;
  source_as_target.build(source_points_, params_);
  PointToPlaneParams target_as_source_params = params_;
  target_as_source_params.target_voxel_size_m = params_.source_voxel_size_m;
  PointToPlaneTarget target_as_source;
  target_as_source.build(target_points_, target_as_source_params);
  const auto inverse = pcl::rast::refinePointToPlane(target_as_source, source_as_target,
                                                     guess.inverse(), params_);
  ASSERT_TRUE(inverse.success) << inverse.message;
  EXPECT_LT(translationError(inverse.T_target_source, T_target_source_.inverse()), 0.01);
  EXPECT_LT(rotationErrorDeg(inverse.T_target_source, T_target_source_.inverse()), 0.05);
}

TEST_F(SyntheticScene, FarGuessFailsInsteadOfReturningIt)
{
  // 40 m away: no source point near the target: failure with a reason.
  const Eigen::Isometry3d guess =
      makeTransform(0, 0, 0, Eigen::Vector3d(0, 0, 40.0)) * T_target_source_;
  const auto result = pcl::rast::refinePointToPlane(source_, target_, guess, params_);
  EXPECT_FALSE(result.success);
  EXPECT_NE(result.message.find("min_correspondences"), std::string::npos) << result.message;
}

TEST_F(SyntheticScene, RunAwayCorrectionIsReportedAsDiverged)
{
  PointToPlaneParams params = params_;
  params.max_correction_m = 0.1; // the true correction is ~0.5 m
  const Eigen::Isometry3d guess =
      makeTransform(0, 0, 0, Eigen::Vector3d(0.5, 0, 0)) * T_target_source_;
  const auto result = pcl::rast::refinePointToPlane(source_, target_, guess, params);
  EXPECT_FALSE(result.success);
  EXPECT_NE(result.message.find("diverged"), std::string::npos) << result.message;
}

TEST(PointToPlaneRefinement, TargetWithGivenNormals)
{
  // A local map with normals: floor and two walls.
  pcl::PointCloud<pcl::PointNormal> map;
  for (int i = -20; i <= 20; ++i)
    for (int j = -20; j <= 20; ++j) {
      pcl::PointNormal p;
      p.getVector3fMap() = Eigen::Vector3f(0.5f * i, 0.5f * j, 0.f);
      p.getNormalVector3fMap() = Eigen::Vector3f::UnitZ();
      map.push_back(p);
      p.getVector3fMap() = Eigen::Vector3f(10.f, 0.5f * i, 5.f + 0.25f * j);
      p.getNormalVector3fMap() = Eigen::Vector3f::UnitX();
      map.push_back(p);
      p.getVector3fMap() = Eigen::Vector3f(0.5f * i, 10.f, 5.f + 0.25f * j);
      p.getNormalVector3fMap() = Eigen::Vector3f::UnitY();
      map.push_back(p);
    }
  PointToPlaneTarget target;
  target.build(map);
  EXPECT_EQ(target.size(), map.size());
  PointVector source;
  for (const auto& p : map.points)
    source.push_back(p.getVector3fMap().cast<double>());
  const Eigen::Isometry3d T = makeTransform(0, 0, 2, Eigen::Vector3d(0.2, -0.1, 0.1));
  source = transformed(T.inverse(), source);
  PointToPlaneParams params;
  params.min_kernel_scale_m = 0.01;
  const auto result =
      pcl::rast::refinePointToPlane(source, target, Eigen::Isometry3d::Identity(), params);
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_LT(translationError(result.T_target_source, T), 0.01);

  pcl::PointCloud<pcl::PointNormal> no_normals;
  no_normals.resize(5);
  for (auto& p : no_normals.points)
    p.getNormalVector3fMap().setZero();
  EXPECT_THROW(target.build(no_normals), std::invalid_argument);
}

TEST(PointToPlaneRefinement, InvalidInputThrows)
{
  PointToPlaneParams params;
  std::string why;
  EXPECT_TRUE(params.isValid(&why)) << why;
  params.max_correspondence_distance_m = -1.0;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("max_correspondence_distance_m"), std::string::npos);
  PointToPlaneTarget empty_target;
  const PointVector source(100, Eigen::Vector3d::Zero());
  EXPECT_THROW(pcl::rast::refinePointToPlane(source, empty_target, Eigen::Isometry3d::Identity(),
                                             params),
               std::invalid_argument);
  EXPECT_THROW(pcl::rast::refinePointToPlane(source, empty_target, Eigen::Isometry3d::Identity()),
               std::invalid_argument);
  EXPECT_THROW(empty_target.build(PointVector(3, Eigen::Vector3d::Zero())), std::invalid_argument);
}

/// A corridor: ground and two long walls, nothing facing along its axis (x).
PointVector
sampleCorridor(std::uint32_t seed)
{
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 0.01);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  PointVector points;
  for (int i = 0; i < 40000; ++i) {
    const double x = -30.0 + 60.0 * u(rng);
    const double which = u(rng);
    Eigen::Vector3d p = which < 0.5    ? Eigen::Vector3d(x, -6.0 + 12.0 * u(rng), 0.0)
                        : which < 0.75 ? Eigen::Vector3d(x, 6.0, 5.0 * u(rng))
                                       : Eigen::Vector3d(x, -6.0, 5.0 * u(rng));
    points.push_back(p + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
  }
  return points;
}

TEST(PointToPlaneRefinement, DegeneracyAwareStepsKeepTheGuessAlongACorridor)
{
  const Eigen::Isometry3d T_true = makeTransform(0.5, -0.3, 2.0, {0.4, 0.2, 0.05});
  PointToPlaneTarget target;
  target.build(sampleCorridor(1), PointToPlaneParams());
  const PointVector source = transformed(T_true.inverse(), sampleCorridor(2));
  // The guess is 0.8 m off along the corridor and 0.3 m across it.
  const Eigen::Isometry3d guess = Eigen::Translation3d(0.8, 0.3, 0.0) * T_true;
  PointToPlaneParams params;
  params.degeneracy_min_ratio = 0.002;
  const auto r = pcl::rast::refinePointToPlane(source, target, guess, params);
  ASSERT_TRUE(r.success) << r.message;
  EXPECT_GE(r.degenerate_directions, 1);
  EXPECT_LT(r.weakest_ratio, 0.002);
  const Eigen::Vector3d off = r.T_target_source.translation() - T_true.translation();
  EXPECT_NEAR(off.x(), 0.8, 0.05) << "the corridor's axis keeps the guess";
  EXPECT_LT(std::abs(off.y()), 0.05) << "across it the walls correct the guess";
  EXPECT_LT(std::abs(off.z()), 0.05);
  EXPECT_LT(rotationErrorDeg(r.T_target_source, T_true), 0.2);

  // Plain steps (the default) report nothing of the kind.
  const auto plain =
      pcl::rast::refinePointToPlane(source, target, guess, PointToPlaneParams());
  EXPECT_EQ(plain.degenerate_directions, 0);
  EXPECT_EQ(plain.weakest_ratio, 0.0);

  // Where the scene constrains every direction, the result is the plain one, exactly.
  const PointVector street = sampleScene(7);
  PointToPlaneTarget street_target;
  street_target.build(street, PointToPlaneParams());
  const Eigen::Isometry3d street_guess = makeTransform(1.0, 0.5, 3.0, {0.3, -0.2, 0.1});
  const auto a =
      pcl::rast::refinePointToPlane(transformed(street_guess.inverse(), sampleScene(8)),
                                    street_target,
                                    street_guess * makeTransform(0, 0, 1, {0.2, 0.1, 0}),
                                    params);
  const auto b =
      pcl::rast::refinePointToPlane(transformed(street_guess.inverse(), sampleScene(8)),
                                    street_target,
                                    street_guess * makeTransform(0, 0, 1, {0.2, 0.1, 0}),
                                    PointToPlaneParams());
  ASSERT_TRUE(a.success) << a.message;
  EXPECT_EQ(a.degenerate_directions, 0);
  EXPECT_GT(a.weakest_ratio, 0.002);
  EXPECT_TRUE(a.T_target_source.matrix() == b.T_target_source.matrix());

  PointToPlaneParams bad;
  std::string why;
  bad.degeneracy_min_ratio = -0.1;
  EXPECT_FALSE(bad.isValid(&why));
  EXPECT_NE(why.find("degeneracy_min_ratio"), std::string::npos);
  bad.degeneracy_min_ratio = std::nan("");
  EXPECT_FALSE(bad.isValid(&why));
}

/// Two threads (PointToPlaneParams::threads) prepare the same planes in the same order
/// as one: each half's voxels merge in order of first appearance.
TEST(PointToPlaneRefinement, TwoThreadsPrepareTheSameTarget)
{
  PointVector points = sampleScene(3, 300);
  points[points.size() / 2 + 7] =
      Eigen::Vector3d(NAN, 0.0, 0.0); // skipped in either half
  ASSERT_GE(points.size(), 40000u);
  PointToPlaneParams one, two;
  two.threads = 2;
  PointToPlaneTarget a, b;
  a.build(points, one);
  b.build(points, two);
  ASSERT_GT(a.size(), 2000u);
  ASSERT_EQ(a.size(), b.size());
  int differ = 0;
  for (std::size_t i = 0; i < a.size(); ++i)
    differ += (a.points()[i] - b.points()[i]).norm() > 1e-9 ||
              std::abs(a.normals()[i].dot(b.normals()[i])) < 1.0 - 1e-9;
  EXPECT_EQ(differ, 0) << "planes differ between one and two threads";

  pcl::PointCloud<pcl::PointXYZI> cloud;
  for (const auto& p : points) {
    pcl::PointXYZI q;
    q.getVector3fMap() = p.cast<float>();
    cloud.push_back(q);
  }
  one.max_source_points = two.max_source_points = 1500; // planes on ~3000 voxels only
  const PointToPlaneTarget sa = pcl::rast::prepareSource(cloud, one);
  const PointToPlaneTarget sb = pcl::rast::prepareSource(cloud, two);
  ASSERT_EQ(sa.size(), sb.size());
  for (std::size_t i = 0; i < sa.size(); ++i)
    ASSERT_LT((sa.points()[i] - sb.points()[i]).norm(), 1e-6) << "source point " << i;

  std::string why;
  two.threads = 3;
  EXPECT_FALSE(two.isValid(&why));
  EXPECT_NE(why.find("threads must be 1 or 2, got 3"), std::string::npos) << why;
}

/// A sparse, rough plane (about one point per 1 m voxel, as a VLP-16 ring far out, 2 cm
/// of noise): a voxel's 3x3x3 block holds fewer than normal_neighbours points, so its
/// plane is fitted to the 5x5x5 block, which the build finds through blocks of 2x2x2
/// voxels. Over negative and positive coordinates every voxel whose block (counted here
/// voxel by voxel) holds enough points has its plane, and its normal is the one of
/// exactly that block's points: one voxel more or less turns it by far more than the
/// tolerance.
TEST(PointToPlaneRefinement, SparseVoxelsFitTheirPlanesOnTheWiderBlock)
{
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> noise(-0.02, 0.02);
  PointVector points;
  for (double x = -12.3; x < 12.0; x += 1.05)
    for (double y = -11.9; y < 12.0; y += 1.05)
      points.emplace_back(x, y, 0.2 * x + 0.1 * y - 3.7 + noise(rng));
  PointToPlaneParams params;
  params.target_voxel_size_m = 1.0;
  using Cell = std::tuple<int, int, int>;
  const auto cellOf = [](const Eigen::Vector3d& p) {
    return Cell{static_cast<int>(std::floor(p.x())),
                static_cast<int>(std::floor(p.y())),
                static_cast<int>(std::floor(p.z()))};
  };
  std::map<Cell, PointVector> voxels;
  for (const auto& p : points)
    voxels[cellOf(p)].push_back(p);
  // The reference: each voxel's plane from the points of its block, 3x3x3 or 5x5x5.
  std::map<Cell, Eigen::Vector3d> expected;
  int wider = 0;
  for (const auto& [key, own] : voxels) {
    PointVector block;
    for (int radius = 1; radius <= 2; ++radius) {
      block.clear();
      for (const auto& [other, inside] : voxels)
        if (std::abs(std::get<0>(other) - std::get<0>(key)) <= radius &&
            std::abs(std::get<1>(other) - std::get<1>(key)) <= radius &&
            std::abs(std::get<2>(other) - std::get<2>(key)) <= radius)
          block.insert(block.end(), inside.begin(), inside.end());
      if (static_cast<int>(block.size()) >= params.normal_neighbours)
        break;
    }
    if (static_cast<int>(block.size()) < params.normal_neighbours)
      continue;
    wider += block.size() > 12; // more than a 3x3x3 block of this grid holds
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& p : block)
      mean += p;
    mean /= static_cast<double>(block.size());
    Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
    for (const auto& p : block)
      covariance += (p - mean) * (p - mean).transpose();
    expected[key] =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(covariance).eigenvectors().col(0);
  }
  ASSERT_GT(wider, 300) << "most voxels need the wider block";
  PointToPlaneTarget target;
  target.build(points, params);
  EXPECT_EQ(target.size(), expected.size());
  for (std::size_t i = 0; i < target.size(); ++i) {
    const auto it = expected.find(cellOf(target.points()[i]));
    ASSERT_NE(it, expected.end()) << "plane " << i << " of no voxel";
    EXPECT_GT(std::abs(target.normals()[i].dot(it->second)), 1.0 - 1e-9)
        << "plane " << i << " at " << target.points()[i].transpose();
  }
}

/// nearest() with a kept CellLookup finds what a fresh search finds, whether the query
/// stays in its cell (the kept slots are used, with the pruning of the fresh search) or
/// leaves it (looked up afresh): random walks with steps from a millimetre to half a
/// metre through a street scene, near facades, boxes and the edges of the data.
TEST(PointToPlaneRefinement, AKeptCellLookupFindsWhatAFreshSearchFinds)
{
  const PointVector points = sampleScene(4);
  PointToPlaneTarget target;
  target.build(points, PointToPlaneParams());
  ASSERT_GT(target.size(), 1000u);
  std::mt19937 rng(11);
  std::uniform_int_distribution<std::size_t> start(0, points.size() - 1);
  std::uniform_real_distribution<double> step_scale(-3.0, -0.3); // 1 mm to 0.5 m
  std::normal_distribution<double> direction(0.0, 1.0);
  int found = 0, kept_cell = 0;
  for (int walk = 0; walk < 200; ++walk) {
    Eigen::Vector3d q = points[start(rng)];
    PointToPlaneTarget::CellLookup lookup;
    std::uint64_t cell_before = lookup.cell;
    for (int step = 0; step < 30; ++step) {
      const Eigen::Vector3d d(direction(rng), direction(rng), direction(rng));
      q += std::pow(10.0, step_scale(rng)) * d.normalized();
      Eigen::Vector3d p_fresh, n_fresh, p_kept, n_kept;
      const bool fresh = target.nearest(q, 1.0, p_fresh, n_fresh);
      const bool kept = target.nearest(q, 1.0, p_kept, n_kept, lookup);
      ASSERT_EQ(fresh, kept) << "walk " << walk << " step " << step;
      kept_cell += lookup.cell == cell_before;
      cell_before = lookup.cell;
      if (!fresh)
        continue;
      ++found;
      ASSERT_EQ(p_fresh, p_kept) << "walk " << walk << " step " << step;
      ASSERT_EQ(n_fresh, n_kept) << "walk " << walk << " step " << step;
    }
  }
  EXPECT_GT(found, 3000);
  EXPECT_GT(kept_cell, 1000) << "the walks should often stay in their cell";

  // A lookup filled on one target and given to another is filled afresh.
  PointToPlaneTarget other;
  other.build(sampleScene(5), PointToPlaneParams());
  int compared = 0;
  for (std::size_t i = 0; i < points.size(); i += 97) {
    PointToPlaneTarget::CellLookup lookup;
    Eigen::Vector3d p1, n1, p_fresh, n_fresh;
    target.nearest(points[i], 1.0, p1, n1, lookup);
    const bool fresh = other.nearest(points[i], 1.0, p_fresh, n_fresh);
    Eigen::Vector3d p_kept, n_kept;
    ASSERT_EQ(other.nearest(points[i], 1.0, p_kept, n_kept, lookup), fresh);
    if (fresh) {
      ++compared;
      ASSERT_EQ(p_kept, p_fresh) << "point " << i;
    }
  }
  EXPECT_GT(compared, 10);
}

/// A source prepared with its points' times (a raw sweep) keeps the planes of the one
/// prepared without, and gives each the mean time of its voxel's points: with times
/// linear in x, the mean time is that of the mean point. Then it refines as the
/// prepared source does, given as points and normals.
TEST(PointToPlaneRefinement, PreparedSourceCarriesTheMeanTimeOfItsVoxels)
{
  const PointVector points = sampleScene(4, 100);
  pcl::PointCloud<pcl::PointXYZI> cloud;
  std::vector<float> times;
  for (const auto& p : points) {
    pcl::PointXYZI q;
    q.getVector3fMap() = p.cast<float>();
    cloud.push_back(q);
    times.push_back(static_cast<float>(1e-3 * p.x()));
  }
  cloud[11].y = std::numeric_limits<float>::quiet_NaN(); // dropped with its time
  PointToPlaneParams params;
  for (const int threads : {1, 2}) {
    params.threads = threads;
    const PointToPlaneTarget plain = pcl::rast::prepareSource(cloud, params);
    std::vector<float> prepared_times;
    const PointToPlaneTarget timed =
        pcl::rast::prepareSource(cloud, times, params, prepared_times);
    ASSERT_GT(plain.size(), 500u);
    ASSERT_EQ(timed.size(), plain.size());
    ASSERT_EQ(prepared_times.size(), timed.size());
    for (std::size_t i = 0; i < timed.size(); ++i) {
      ASSERT_EQ(timed.points()[i], plain.points()[i]) << i;
      ASSERT_EQ(timed.normals()[i], plain.normals()[i]) << i;
      ASSERT_NEAR(prepared_times[i], 1e-3 * timed.points()[i].x(), 1e-6) << i;
    }
    // Refined as points and normals, as the prepared source itself.
    PointToPlaneTarget target;
    target.build(sampleScene(5, 100), params);
    const Eigen::Isometry3d guess = makeTransform(0.5, 0.0, 1.0, {0.2, -0.1, 0.0});
    const pcl::rast::PointToPlaneResult a =
        pcl::rast::refinePointToPlane(timed, target, guess, params);
    const pcl::rast::PointToPlaneResult b = pcl::rast::refinePointToPlane(
        timed.points(), timed.normals(), target, guess, params);
    ASSERT_TRUE(a.success) << a.message;
    EXPECT_TRUE(a.T_target_source.isApprox(b.T_target_source, 1e-12));
    EXPECT_EQ(a.num_correspondences, b.num_correspondences);
    EXPECT_LT(translationError(a.T_target_source, Eigen::Isometry3d::Identity()), 0.02);
  }
  std::vector<float> out;
  try {
    pcl::rast::prepareSource(cloud, std::vector<float>(7, 0.0f), params, out);
    ADD_FAILURE() << "a time count that is not the point count must throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("7 times for"), std::string::npos) << e.what();
  }
  PointToPlaneTarget target;
  target.build(points, params);
  const PointVector some(10, Eigen::Vector3d::Zero());
  try {
    pcl::rast::refinePointToPlane(some,
                                  PointVector(9, Eigen::Vector3d::UnitZ()),
                                  target,
                                  Eigen::Isometry3d::Identity(),
                                  params);
    ADD_FAILURE() << "a normal count that is not the point count must throw";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("9 normals for 10 points"), std::string::npos)
        << e.what();
  }
}

// ---------------------------------------------------------------- real scan pairs

/// Refine from identity; print accuracy with and without refinement and timings.
pcl::rast::PointToPlaneResult
registerPair(const pcl::PointCloud<pcl::PointXYZI>& source,
             const pcl::PointCloud<pcl::PointXYZI>& target,
             const Eigen::Isometry3d& reference,
             const std::string& name)
{
  using Clock = std::chrono::steady_clock;
  const PointToPlaneParams params;
  const auto t0 = Clock::now();
  PointToPlaneTarget prepared;
  prepared.build(target, params);
  const auto t1 = Clock::now();
  const PointToPlaneTarget source_planes = pcl::rast::prepareSource(source, params);
  const auto t2 = Clock::now();
  const auto result = pcl::rast::refinePointToPlane(source_planes, prepared,
                                                    Eigen::Isometry3d::Identity(), params);
  const auto t3 = Clock::now();
  auto ms = [](auto a, auto b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
  std::cout << "[ " << name << " ] identity guess: " << 100.0 * reference.translation().norm()
            << " cm, " << rotationErrorDeg(Eigen::Isometry3d::Identity(), reference)
            << " deg off; refined: " << 100.0 * translationError(result.T_target_source, reference)
            << " cm, " << rotationErrorDeg(result.T_target_source, reference) << " deg ("
            << result.message << ", rmse " << result.rmse_m << " m)\n"
            << "[ " << name << " ] target " << target.size() << " -> " << prepared.size()
            << " planar points in " << ms(t0, t1) << " ms; source " << source.size() << " -> "
            << source_planes.size() << " planar voxels in " << ms(t1, t2) << " ms; ICP " << ms(t2, t3)
            << " ms\n";
  return result;
}

TEST(PointToPlaneRefinementRealData, ScanPairPly)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const auto dir = data / "scan-pair-ply";
  pcl::PointCloud<pcl::PointXYZI> source, target;
  ASSERT_EQ(pcl::io::loadPLYFile((dir / "source.ply").string(), source), 0);
  ASSERT_EQ(pcl::io::loadPLYFile((dir / "target.ply").string(), target), 0);
  const Eigen::Isometry3d reference = readMatrix4(dir / "T_target_source.txt");
  ASSERT_GT(reference.translation().norm(), 0.3);
  const auto result = registerPair(source, target, reference, "scan-pair-ply");
  ASSERT_TRUE(result.success) << result.message;
  // Spec: 5 cm and 0.2 deg against small_gicp's reference (measured 1.7 cm, 0.16 deg).
  EXPECT_LE(translationError(result.T_target_source, reference), 0.05);
  EXPECT_LE(rotationErrorDeg(result.T_target_source, reference), 0.2);
}

TEST(PointToPlaneRefinementRealData, ScanPairPcdRelativeIsTargetFromSource)
{
  // fast_gicp's pair: target 251370668.pcd, source 251371071.pcd, and relative.txt is
  // T_target_source (the same scans as small_gicp's target.ply / source.ply). Checked
  // here: the refinement lands on relative.txt, far from its inverse.
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const auto dir = data / "scan-pair-pcd";
  pcl::PointCloud<pcl::PointXYZI> source, target;
  ASSERT_EQ(pcl::io::loadPCDFile((dir / "251371071.pcd").string(), source), 0);
  ASSERT_EQ(pcl::io::loadPCDFile((dir / "251370668.pcd").string(), target), 0);
  const Eigen::Isometry3d reference = readMatrix4(dir / "relative.txt");
  const auto result = registerPair(source, target, reference, "scan-pair-pcd");
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_LE(translationError(result.T_target_source, reference), 0.05);
  // relative.txt and small_gicp's T_target_source.txt disagree by 1.9 cm and 0.23 deg
  // (0.21 deg of it in roll); the refinement lands 0.16 deg from the latter and 0.38 deg
  // from this one, so 0.2 deg to both is not a meaningful spec here (doc/registration.md).
  EXPECT_LE(rotationErrorDeg(result.T_target_source, reference), 0.45);
  EXPECT_GT(translationError(result.T_target_source, reference.inverse()), 0.5);
}

} // namespace

} // namespace test_point_to_plane_refinement
