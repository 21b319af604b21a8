/// \file bench_rejection.cpp
/// \brief Why pcl_rast keeps its own rigid RANSAC and least squares next to PCL's
/// CorrespondenceRejectorSampleConsensus and TransformationEstimationSVD
/// (doc/registration.md). Real data: ORB features of the 22 KITTI raw scans
/// (kitti-raw-22, HDL-64), Hamming matches between frames i and i + gap. Each method
/// turns the same matches into a rigid transform; its error is measured against the
/// densely refined registration of the pair. Counters: mean translation error [cm],
/// mean rotation error [deg], pairs off by more than 0.3 m or 2 deg, mean inliers.
///   bench_rejection --benchmark_repetitions=5 --benchmark_report_aggregates_only=true

#include <pcl/features/orb_raster_features.h>
#include <pcl/registration/correspondence_rejection_sample_consensus.h>
#include <pcl/registration/correspondence_rigid_registration.h>
#include <pcl/registration/transformation_estimation_svd.h>
#include <pcl/registration/umeyama_estimation.h>
#include <pcl/segmentation/sac_ground_removal.h>
// PCL's sample-consensus templates for the descriptor point type.
#include <benchmark/benchmark.h>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <pcl/io/pcd_io.h>
#include <pcl/sample_consensus/impl/ransac.hpp>
#include <pcl/sample_consensus/impl/sac_model_registration.hpp>
#include <string>
#include <vector>

namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZI>;
using Features = pcl::PointCloud<pcl::rast::ORBSignature256>;

std::filesystem::path
sharedDataDir()
{
  if (const char* env = std::getenv("PCL_RAST_DATA_DIR"))
    return env;
  return PCL_RAST_SHARED_DATA_DIR;
}

/// One pair's matches and the reference transform.
struct PairCase
{
  pcl::rast::RasterFeatureSet source, target;
  Features::Ptr source_cloud, target_cloud;
  pcl::CorrespondencesPtr matches;
  Eigen::Isometry3d reference;
};

struct Scan
{
  Cloud::Ptr cloud;
  pcl::rast::RasterFeatureSet features;
};

std::vector<Scan>
loadScans()
{
  std::vector<Scan> scans;
  const auto dir = sharedDataDir() / "kitti-raw-22" / "pcd";
  for (int i = 0; i < 22; ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "%010d.pcd", i);
    Scan scan;
    scan.cloud = std::make_shared<Cloud>();
    if (pcl::io::loadPCDFile((dir / name).string(), *scan.cloud) != 0)
      return {};
    pcl::rast::SACGroundRemoval<pcl::PointXYZI> ground;
    ground.setInputCloud(scan.cloud);
    auto non_ground = std::make_shared<pcl::Indices>();
    ground.filter(*non_ground);
    pcl::rast::OrbRasterFeatureEstimator<pcl::PointXYZI> orb;
    orb.setInputCloud(scan.cloud);
    orb.setIndices(non_ground);
    orb.compute(scan.features);
    scans.push_back(std::move(scan));
  }
  return scans;
}

const std::vector<PairCase>&
cases(int gap)
{
  static const std::vector<Scan> scans = loadScans();
  static std::vector<PairCase> by_gap[4];
  auto& out = by_gap[gap];
  if (!out.empty() || scans.empty())
    return out;
  for (std::size_t i = 0; i + gap < scans.size(); ++i) {
    PairCase c;
    c.source = scans[i + gap].features;
    c.target = scans[i].features;
    c.source_cloud = std::make_shared<Features>();
    c.target_cloud = std::make_shared<Features>();
    pcl::rast::toSignatureCloud(c.source, *c.source_cloud);
    pcl::rast::toSignatureCloud(c.target, *c.target_cloud);
    c.matches = std::make_shared<pcl::Correspondences>(
        pcl::rast::matchHamming(c.source, c.target));
    // Reference: the full chain with the dense point-to-plane refinement.
    pcl::rast::CorrespondenceRigidRegistration reg;
    reg.setInputSource(std::make_shared<pcl::rast::RasterFeatureSet>(c.source),
                       scans[i + gap].cloud);
    reg.setInputTarget(std::make_shared<pcl::rast::RasterFeatureSet>(c.target),
                       scans[i].cloud);
    const auto r = reg.align();
    if (!r.success || !r.refined)
      continue;
    c.reference = r.T_target_source;
    out.push_back(std::move(c));
  }
  return out;
}

/// Error counters over all pairs of one benchmark iteration.
struct Accuracy
{
  double t_cm = 0.0, r_deg = 0.0, inliers = 0.0;
  int failures = 0, n = 0;

  void add(const Eigen::Matrix4d& T,
           const Eigen::Isometry3d& reference,
           std::size_t num_inliers)
  {
    const Eigen::Matrix4d E = reference.matrix().inverse() * T;
    const double t = E.topRightCorner<3, 1>().norm();
    const double r = Eigen::AngleAxisd(Eigen::Matrix3d(E.topLeftCorner<3, 3>())).angle() *
                     180.0 / M_PI;
    t_cm += 100.0 * t;
    r_deg += r;
    inliers += static_cast<double>(num_inliers);
    failures += (t > 0.3 || r > 2.0);
    ++n;
  }
  void report(benchmark::State& state) const
  {
    state.counters["t_err_cm"] = n ? t_cm / n : 0.0;
    state.counters["r_err_deg"] = n ? r_deg / n : 0.0;
    state.counters["failures"] = failures;
    state.counters["inliers"] = n ? inliers / n : 0.0;
    state.counters["pairs"] = n;
  }
};

/// Times \a estimate(k, pair, accuracy) over every pair of frames i, i + \a gap and
/// reports the accuracy of the last pass.
template <typename Estimate>
void
runOverPairs(benchmark::State& state, int gap, Estimate estimate)
{
  const auto& all = cases(gap);
  if (all.empty()) {
    state.SkipWithError("../shared/data/kitti-raw-22 not found");
    return;
  }
  Accuracy accuracy;
  for (auto _ : state) {
    accuracy = Accuracy();
    for (std::size_t k = 0; k < all.size(); ++k)
      estimate(k, all[k], accuracy);
  }
  accuracy.report(state);
}

/// pcl_rast: seeded RANSAC with adaptive iterations and degenerate-sample checks, then
/// Umeyama on the inliers.
void
BM_RastRansac(benchmark::State& state)
{
  runOverPairs(
      state,
      static_cast<int>(state.range(0)),
      [](std::size_t, const PairCase& c, Accuracy& accuracy) {
        const auto r =
            pcl::rast::estimateRigidRansac(c.source.points, c.target.points, *c.matches);
        accuracy.add(r.T_target_source.matrix(), c.reference, r.inlier_indices.size());
      });
}

/// PCL: CorrespondenceRejectorSampleConsensus (fixed iteration budget), then
/// TransformationEstimationSVD on its inliers.
void
BM_PclRejectorSvd(benchmark::State& state)
{
  const int max_iterations = static_cast<int>(state.range(1));
  runOverPairs(
      state,
      static_cast<int>(state.range(0)),
      [max_iterations](std::size_t, const PairCase& c, Accuracy& accuracy) {
        pcl::registration::CorrespondenceRejectorSampleConsensus<
            pcl::rast::ORBSignature256>
            rejector;
        rejector.setInputSource(c.source_cloud);
        rejector.setInputTarget(c.target_cloud);
        rejector.setInlierThreshold(0.5);
        rejector.setMaximumIterations(max_iterations);
        rejector.setInputCorrespondences(c.matches);
        pcl::Correspondences inliers;
        rejector.getCorrespondences(inliers);
        pcl::registration::TransformationEstimationSVD<pcl::rast::ORBSignature256,
                                                       pcl::rast::ORBSignature256>
            svd;
        Eigen::Matrix4f T = Eigen::Matrix4f::Identity();
        if (inliers.size() >= 3)
          svd.estimateRigidTransformation(*c.source_cloud, *c.target_cloud, inliers, T);
        accuracy.add(T.cast<double>(), c.reference, inliers.size());
      });
}

/// Least squares alone on the same inliers (pcl_rast's RANSAC inliers of each
/// consecutive pair): pcl_rast's Umeyama (0) and PCL's SVD (1).
void
BM_LeastSquares(benchmark::State& state)
{
  std::vector<pcl::Correspondences> inliers;
  for (const auto& c : cases(1)) {
    const auto r =
        pcl::rast::estimateRigidRansac(c.source.points, c.target.points, *c.matches);
    inliers.emplace_back();
    for (const int k : r.inlier_indices)
      inliers.back().push_back((*c.matches)[k]);
  }
  const bool pcl_svd = state.range(0) == 1;
  runOverPairs(state, 1, [&](std::size_t k, const PairCase& c, Accuracy& accuracy) {
    Eigen::Matrix4d T;
    if (pcl_svd) {
      pcl::registration::TransformationEstimationSVD<pcl::rast::ORBSignature256,
                                                     pcl::rast::ORBSignature256>
          svd;
      Eigen::Matrix4f Tf;
      svd.estimateRigidTransformation(*c.source_cloud, *c.target_cloud, inliers[k], Tf);
      T = Tf.cast<double>();
    } else {
      T = pcl::rast::estimateRigidTransform(c.source.points, c.target.points, inliers[k])
              .T_target_source.matrix();
    }
    accuracy.add(T, c.reference, inliers[k].size());
  });
}

} // namespace

// Arguments: the frame gap of the pairs (1: consecutive, 3: 2.4 m apart); for PCL also
// its iteration budget (1000 is PCL's default, 10000 pcl_rast's cap).
BENCHMARK(BM_RastRansac)->Arg(1)->Arg(3)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_PclRejectorSvd)
    ->Args({1, 1000})
    ->Args({1, 10000})
    ->Args({3, 1000})
    ->Args({3, 10000})
    ->Unit(benchmark::kMillisecond);
// 0: pcl_rast's Umeyama, 1: PCL's TransformationEstimationSVD.
BENCHMARK(BM_LeastSquares)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

BENCHMARK_MAIN();
