/// \file test_dense_core.cpp
/// \brief The dense-registration core shared by the refinement, the odometry and the map
/// builder: voxel keys, the open-addressing voxel hash map, the first-point downsampler
/// and the point-to-plane normal equations (plain and degeneracy-aware solves).

#include <cmath>
#include <gtest/gtest.h>
#include <map>
#include <pcl/registration/point_to_plane_system.h>
#include <pcl/registration/voxel_hash_map.h>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_dense_core {

namespace {

using pcl::rast::packVoxelKey;
using pcl::rast::PointToPlaneSystem;
using pcl::rast::voxelCoordinate;
using pcl::rast::VoxelHashMap;
using pcl::rast::VoxelKey;
using pcl::rast::VoxelOccupancy;

TEST(VoxelKey, CoordinateIsTheFloorAndKeysOrderAsCoordinates)
{
  const double inv = 1.0 / 0.3;
  for (const double v : {-10.0, -0.3, -0.29, -1e-9, 0.0, 1e-9, 0.29, 0.3, 0.61, 1234.5})
    EXPECT_EQ(voxelCoordinate(v, inv), static_cast<std::int64_t>(std::floor(v * inv)))
        << v;
  // Signed coordinates order lexicographically (x, y, z) as their keys do.
  EXPECT_LT(packVoxelKey(-1, 5, 5), packVoxelKey(0, -5, -5));
  EXPECT_LT(packVoxelKey(0, -1, 9), packVoxelKey(0, 0, -9));
  EXPECT_LT(packVoxelKey(0, 0, -1), packVoxelKey(0, 0, 0));
  // Distinct within the +-2^20 range.
  EXPECT_NE(packVoxelKey(-(1 << 20), 0, 0), packVoxelKey((1 << 20) - 1, 0, 0));
}

TEST(VoxelHashMap, AgreesWithStdMapThroughGrowth)
{
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> coordinate(-300, 300);
  VoxelHashMap hash;
  hash.reset(4); // far too small: must grow many times
  std::map<VoxelKey, int> reference;
  for (int i = 0; i < 20000; ++i) {
    const VoxelKey key =
        packVoxelKey(coordinate(rng), coordinate(rng), coordinate(rng) / 30);
    const auto [value, inserted] = hash.insert(key, i);
    const auto [it, ref_inserted] = reference.emplace(key, i);
    ASSERT_EQ(inserted, ref_inserted);
    ASSERT_EQ(value, it->second);
  }
  EXPECT_EQ(hash.size(), reference.size());
  for (const auto& [key, value] : reference)
    ASSERT_EQ(hash.find(key), value);
  EXPECT_EQ(hash.find(packVoxelKey(1000, 1000, 1000)), -1);
  EXPECT_EQ(VoxelHashMap().find(packVoxelKey(0, 0, 0)), -1); // never reset: empty
}

TEST(VoxelOccupancy, KeepsTheFirstPointOfEachVoxelInInputOrder)
{
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-5.0, 5.0);
  const double voxel = 0.5;
  std::set<std::tuple<long, long, long>> seen;
  VoxelOccupancy occupancy(voxel, 4);
  int kept = 0;
  for (int i = 0; i < 5000; ++i) {
    // Runs of repeated points exercise the last-key shortcut.
    const Eigen::Vector3d p(u(rng), u(rng), u(rng) * 0.2);
    for (int repeat = 0; repeat < 1 + i % 3; ++repeat) {
      const auto cell = std::make_tuple(static_cast<long>(std::floor(p.x() / voxel)),
                                        static_cast<long>(std::floor(p.y() / voxel)),
                                        static_cast<long>(std::floor(p.z() / voxel)));
      const bool first = seen.insert(cell).second;
      ASSERT_EQ(occupancy.insert(p), first) << "point " << i << " repeat " << repeat;
      kept += first;
    }
  }
  EXPECT_EQ(occupancy.size(), static_cast<std::size_t>(kept));
  // Float points key as their double values do.
  VoxelOccupancy float_occupancy(voxel);
  EXPECT_TRUE(float_occupancy.insert(Eigen::Vector3f(0.1f, 0.1f, 0.1f)));
  EXPECT_FALSE(float_occupancy.insert(Eigen::Vector3f(0.4f, 0.2f, 0.3f)));
  EXPECT_TRUE(float_occupancy.insert(Eigen::Vector3f(-0.1f, 0.1f, 0.1f)));
}

TEST(DenseCore, InvalidSizesThrowNamingTheValue)
{
  for (const double bad : {0.0, -0.5, std::nan(""), HUGE_VAL}) {
    EXPECT_THROW(VoxelOccupancy{bad}, std::invalid_argument) << bad;
    EXPECT_THROW(PointToPlaneSystem{bad}, std::invalid_argument) << bad;
  }
  try {
    VoxelOccupancy occupancy(-0.5);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("voxel_size_m"), std::string::npos) << e.what();
  }
}

/// Residuals of a known small motion of points on three orthogonal planes (or the
/// ground only): one Gauss-Newton step undoes it.
PointToPlaneSystem
systemOfKnownMotion(const Eigen::Matrix<double, 6, 1>& motion,
                    double rotation_length_m,
                    bool only_ground)
{
  PointToPlaneSystem system(rotation_length_m);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-10.0, 10.0);
  const Eigen::Vector3d omega = motion.head<3>() / rotation_length_m;
  const Eigen::Vector3d dt = motion.tail<3>();
  for (int i = 0; i < 300; ++i) {
    const int axis = only_ground ? 2 : i % 3;
    Eigen::Vector3d q(u(rng), u(rng), u(rng));
    q[axis] = axis == 2 ? -1.7 : 8.0; // a point on the plane x = 8, y = 8 or z = -1.7
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    n[axis] = 1.0;
    // The point moved by the linearised motion, q + omega x q + dt: its residual
    // against its plane, linearised at q.
    const double r = n.dot(omega.cross(q) + dt);
    system.addPointToPlane(q, n, r, 1.0);
  }
  return system;
}

TEST(PointToPlaneSystem, OneStepUndoesASmallMotion)
{
  Eigen::Matrix<double, 6, 1> motion;
  motion << 0.002, -0.001, 0.003, 0.05, -0.02, 0.01;
  for (const double length : {1.0, 10.0}) {
    Eigen::Matrix<double, 6, 1> scaled = motion;
    scaled.head<3>() *= length;
    const PointToPlaneSystem system = systemOfKnownMotion(scaled, length, false);
    Eigen::Matrix<double, 6, 1> dx;
    ASSERT_TRUE(system.solve(dx));
    EXPECT_LT((dx + scaled).norm(), 1e-9) << "length " << length;
    const PointToPlaneSystem::Step step = system.solveDegeneracyAware(0.003);
    EXPECT_EQ(step.degenerate_directions, 0);
    EXPECT_LT((step.dx + scaled).norm(), 1e-9);
    EXPECT_GT(step.weakest_ratio, 0.003);
    EXPECT_NEAR(system.sumWeights(), 300.0, 1e-9);
  }
}

TEST(PointToPlaneSystem, GroundOnlyLeavesThreeDirectionsAtTheStartOrTheAnchor)
{
  Eigen::Matrix<double, 6, 1> motion;
  motion << 0.01, -0.02, 0.0, 0.0, 0.0, 0.03; // roll, pitch, z: what a ground plane sees
  const PointToPlaneSystem system = systemOfKnownMotion(motion, 10.0, true);
  const PointToPlaneSystem::Step step = system.solveDegeneracyAware(0.003);
  EXPECT_EQ(step.degenerate_directions, 3); // yaw, x, y
  EXPECT_LT((step.dx + motion).norm(), 1e-6);
  // An anchor 1 m away along x: the step moves there along the unconstrained x only.
  Eigen::Matrix<double, 6, 1> to_anchor = Eigen::Matrix<double, 6, 1>::Zero();
  to_anchor(3) = 1.0;
  to_anchor(5) = 0.5; // z is constrained: the anchor's z is ignored
  const PointToPlaneSystem::Step anchored =
      system.solveDegeneracyAware(0.003, &to_anchor);
  EXPECT_NEAR(anchored.dx(3), 1.0, 1e-9);
  EXPECT_NEAR(anchored.dx(4), 0.0, 1e-9);
  EXPECT_NEAR(anchored.dx(5), -motion(5), 1e-6);
}

/// A corridor along x: ground, and two walls whose normals lean up to +-10 deg along
/// the corridor (normals fitted to noisy points), plus \a fixtures points on surfaces
/// that face along it. The residuals are those of a small motion along x.
PointToPlaneSystem
corridorSystem(int fixtures, bool keep_rows)
{
  PointToPlaneSystem system(10.0);
  system.keepRows(keep_rows);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> along(-30.0, 30.0), up(-1.5, 3.0),
      lean(-0.17, 0.17);
  const Eigen::Vector3d dt(0.2, 0.0, 0.0);
  auto add = [&](const Eigen::Vector3d& q, const Eigen::Vector3d& n) {
    system.addPointToPlane(q, n, n.dot(dt), 1.0);
  };
  for (int i = 0; i < 600; ++i) {
    const double x = along(rng);
    if (i % 3 == 0) {
      add({x, 0.1 * x, -1.7}, Eigen::Vector3d::UnitZ());
      continue;
    }
    const double side = i % 3 == 1 ? 1.0 : -1.0;
    add({x, 4.0 * side, up(rng)}, Eigen::Vector3d(lean(rng), -side, 0.0).normalized());
  }
  for (int i = 0; i < fixtures; ++i)
    add({12.0, 3.5, 0.5 + 0.01 * i}, -Eigen::Vector3d::UnitX());
  return system;
}

TEST(PointToPlaneSystem, SupportTestFlagsADirectionOnlyLeaningNormalsConstrain)
{
  const PointToPlaneSystem walls = corridorSystem(0, true);
  // The leaning normals pass the eigenvalue test along the corridor ...
  const PointToPlaneSystem::Step plain = walls.solveDegeneracyAware(0.003);
  EXPECT_EQ(plain.degenerate_directions, 0);
  EXPECT_LT(plain.least_support, 0.0); // no support test
  // ... but no point faces along it: the support test keeps the start there.
  const PointToPlaneSystem::Step tested =
      walls.solveDegeneracyAware(0.003, nullptr, 10.0, 0.3);
  EXPECT_EQ(tested.degenerate_directions, 1);
  EXPECT_GE(tested.least_support, 0.0);
  EXPECT_LT(tested.least_support, 10.0);
  EXPECT_NEAR(tested.dx(3), 0.0, 0.02);
  EXPECT_NEAR(tested.dx(5), 0.0, 1e-4);
  // 20 points on a fixture that faces along it support it: the motion is undone.
  const PointToPlaneSystem fixture = corridorSystem(20, true);
  const PointToPlaneSystem::Step supported =
      fixture.solveDegeneracyAware(0.003, nullptr, 10.0, 0.3);
  EXPECT_EQ(supported.degenerate_directions, 0);
  EXPECT_GE(supported.least_support, 10.0);
  EXPECT_NEAR(supported.dx(3), -0.2, 1e-6);
  // A support test needs the rows.
  EXPECT_THROW(corridorSystem(0, false).solveDegeneracyAware(0.003, nullptr, 10.0),
               std::logic_error);
}

TEST(PointToPlaneSystem, AStepPriorHoldsTheWeakDirectionAndBarelyTheOthers)
{
  // The leaning walls' corridor: along it 0.2 m of motion seen only by tilted normals.
  PointToPlaneSystem walls = corridorSystem(0, false);
  const PointToPlaneSystem::Step free = walls.solveDegeneracyAware(0.003);
  ASSERT_EQ(free.degenerate_directions, 0);
  EXPECT_NEAR(free.dx(3), -0.2, 1e-6); // the data alone follow the leaning normals
  // A prior at the start (target 0) with 1 % of the weight: the weak direction stays
  // near it, the constrained ones (z from the ground, y from the walls) hardly feel it.
  walls.setStepPrior(Eigen::Matrix<double, 6, 1>::Zero(), 0.01 * walls.sumWeights());
  const PointToPlaneSystem::Step held = walls.solveDegeneracyAware(0.003);
  EXPECT_EQ(held.degenerate_directions, 0);
  EXPECT_GT(held.dx(3), -0.1);
  EXPECT_LT(held.dx(3), 0.0);
  EXPECT_NEAR(held.dx(4), free.dx(4), 0.01);
  EXPECT_NEAR(held.dx(5), free.dx(5), 0.01);
  // The data's information and weakest direction are reported, not the prior's.
  EXPECT_NEAR(held.weakest_ratio, free.weakest_ratio, 1e-9);
  EXPECT_LT((held.information - free.information).norm(), 1e-12);
  // A prior elsewhere pulls the weak direction toward it.
  Eigen::Matrix<double, 6, 1> target = Eigen::Matrix<double, 6, 1>::Zero();
  target(3) = 0.5;
  walls.setStepPrior(target, 0.01 * walls.sumWeights());
  EXPECT_GT(walls.solveDegeneracyAware(0.003).dx(3), held.dx(3) + 0.1);
}

TEST(PointToPlaneSystem, TangentScalesRotationByTheLength)
{
  Eigen::Isometry3d from = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d to = Eigen::Isometry3d::Identity();
  to.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  to.translation() = Eigen::Vector3d(1.0, 2.0, 3.0);
  const auto delta = PointToPlaneSystem(10.0).tangent(from, to);
  EXPECT_NEAR(delta(2), 1.0, 1e-12);
  EXPECT_NEAR(delta.head<2>().norm(), 0.0, 1e-12);
  EXPECT_NEAR((delta.tail<3>() - Eigen::Vector3d(1.0, 2.0, 3.0)).norm(), 0.0, 1e-12);
}

TEST(RobustWeight, KernelsDownWeightLargeResiduals)
{
  using pcl::rast::RobustKernel;
  using pcl::rast::robustWeight;
  for (const auto kernel :
       {RobustKernel::kHuber, RobustKernel::kTukey, RobustKernel::kGemanMcClure}) {
    EXPECT_NEAR(robustWeight(kernel, 0.0, 0.1), 1.0, 1e-12);
    EXPECT_LT(robustWeight(kernel, 1.0, 0.1), robustWeight(kernel, 0.2, 0.1));
  }
  EXPECT_EQ(robustWeight(RobustKernel::kNone, 5.0, 0.1), 1.0);
  EXPECT_EQ(robustWeight(RobustKernel::kTukey, 0.5, 0.1), 0.0); // beyond 4.685 s
  EXPECT_NEAR(robustWeight(RobustKernel::kGemanMcClure, 0.1, 0.1), 0.25, 1e-12);
}

} // namespace

} // namespace test_dense_core
