/// \file loop_detector.cpp
/// \brief Loop candidates (distance + multi-index-hashing appearance retrieval) and
/// their verification (ratio-test matching, seeded RANSAC, inlier count / ratio /
/// spread, uniqueness, odometry consistency, dense point-to-plane check).

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <pcl/slam/loop_detector.h>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace pcl {
namespace rast {

namespace {

constexpr int kSubstringBits = 16;
constexpr int kMaxHashTables = 256 / kSubstringBits;
constexpr double kDegPerRad = 180.0 / 3.14159265358979323846;

using Clock = std::chrono::steady_clock;

double
msSince(Clock::time_point start)
{
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

/// The 16-bit substring \a table of a descriptor, as a key of the inverted index.
std::uint32_t
substringKey(const OrbDescriptor& d, int table)
{
  const auto lo = static_cast<std::uint32_t>(d[2 * table]);
  const auto hi = static_cast<std::uint32_t>(d[2 * table + 1]);
  return (static_cast<std::uint32_t>(table) << kSubstringBits) | (hi << 8) | lo;
}

double
rotationDeg(const Pose3d& T)
{
  return Eigen::AngleAxisd(T.rotation()).angle() * kDegPerRad;
}

/// Motion between consecutive key-frames: the tracking's relative pose when \a kf
/// directly follows the key-frame at \a T_world_previous, else the pose difference.
double
stepLength(const KeyFrame& kf,
           const Pose3d& T_world_kf,
           KeyFrameId previous_id,
           const Pose3d& T_world_previous)
{
  if (kf.id == previous_id + 1 && !kf.T_previous_keyframe.isApprox(Pose3d::Identity()))
    return kf.T_previous_keyframe.translation().norm();
  return (T_world_kf.translation() - T_world_previous.translation()).norm();
}

std::string
format(const char* fmt, double a, double b = 0.0, double c = 0.0, double d = 0.0)
{
  char buffer[256];
  std::snprintf(buffer, sizeof(buffer), fmt, a, b, c, d);
  return buffer;
}

/// Cells occupied by the inliers' x-y positions and their smaller principal std.
void
inlierSpread(const pcl::PointCloud<RasterFeaturePoint>& points,
             const pcl::Correspondences& matches,
             const std::vector<int>& inliers,
             double cell_size_m,
             int& cells,
             double& spread_m)
{
  std::set<std::pair<long, long>> occupied;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const int k : inliers) {
    const auto& p = points[matches[k].index_query];
    occupied.emplace(static_cast<long>(std::floor(p.x / cell_size_m)),
                     static_cast<long>(std::floor(p.y / cell_size_m)));
    mean += Eigen::Vector2d(p.x, p.y);
  }
  cells = static_cast<int>(occupied.size());
  spread_m = 0.0;
  if (inliers.size() < 2)
    return;
  mean /= static_cast<double>(inliers.size());
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const int k : inliers) {
    const auto& p = points[matches[k].index_query];
    const Eigen::Vector2d d = Eigen::Vector2d(p.x, p.y) - mean;
    cov += d * d.transpose();
  }
  cov /= static_cast<double>(inliers.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(cov);
  spread_m = std::sqrt(std::max(0.0, eig.eigenvalues()(0)));
}

/// The best rigid motion mapping a feature set onto itself elsewhere (each feature
/// paired with its nearest descriptor more than \a min_shift_m away): in a street of
/// equal blocks, the block period. Returns its inlier count and shift length.
int
selfSimilarity(const RasterFeatureSet& f,
               const RigidRansacParams& ransac_params,
               int max_hamming,
               double min_shift_m,
               double& shift_m)
{
  shift_m = 0.0;
  const std::size_t n = f.size();
  pcl::Correspondences pairs;
  const float min_sq = static_cast<float>(min_shift_m * min_shift_m);
  constexpr int kPerFeature = 3;         // a repeated feature has copies on both sides
  std::vector<std::pair<int, int>> best; // (distance, j)
  for (std::size_t i = 0; i < n; ++i) {
    best.clear();
    const Eigen::Vector3f pi = f.points[i].getVector3fMap();
    for (std::size_t j = 0; j < n; ++j) {
      if ((f.points[j].getVector3fMap() - pi).squaredNorm() < min_sq)
        continue;
      const int d = hammingDistance(f.descriptors[i], f.descriptors[j]);
      if (d <= max_hamming)
        best.emplace_back(d, static_cast<int>(j));
    }
    const auto keep = std::min<std::size_t>(kPerFeature, best.size());
    std::partial_sort(best.begin(), best.begin() + keep, best.end());
    for (std::size_t k = 0; k < keep; ++k)
      pairs.emplace_back(
          static_cast<int>(i), best[k].second, static_cast<float>(best[k].first));
  }
  if (static_cast<int>(pairs.size()) < ransac_params.min_inliers)
    return 0;
  const RigidRansacResult r =
      estimateRigidRansac(f.points, f.points, pairs, ransac_params);
  if (!r.success || r.T_target_source.translation().norm() < min_shift_m)
    return 0;
  shift_m = r.T_target_source.translation().norm();
  return static_cast<int>(r.inlier_indices.size());
}

/// \a cloud voxelized at \a voxel_m and cropped to \a radius_m around the sensor (x-y).
PointVector
cropped(const pcl::PointCloud<pcl::PointXYZI>& cloud, double voxel_m, double radius_m)
{
  PointVector points = voxelDownsample(toPointVector(cloud), voxel_m);
  const double r_sq = radius_m * radius_m;
  points.erase(std::remove_if(points.begin(),
                              points.end(),
                              [r_sq](const Eigen::Vector3d& p) {
                                return p.head<2>().squaredNorm() > r_sq;
                              }),
               points.end());
  return points;
}

constexpr double kDenseResolutionM = 0.01; // int16: +-327 m, far beyond the crop radius

/// Steps 1-3 of a verification: the matches and the first RANSAC estimate.
struct FirstEstimate
{
  pcl::Correspondences matches;
  RigidRansacResult ransac;
  RigidRansacParams ransac_params; ///< params_.ransac with min_initial_inliers
};

/// Step 4: the guided matches and their RANSAC.
struct GuidedEstimate
{
  pcl::Correspondences matches;
  RigidRansacResult ransac;
};

/// Steps 1-3: ORB matches with the ratio test (paper), seeded RANSAC on them (paper),
/// and the inlier ratio: in a repetitive scene many matches agree with no single
/// motion. When that fails, the same under the odometry guess (distance candidates):
/// the gate, not the ratio test, keeps the matches apart; RANSAC sorts out the nearest
/// descriptors. Returns why the pair is rejected, or nothing.
std::string
firstEstimate(const LoopDetectorParams& params,
              const KeyFrame& query,
              const KeyFrame& candidate,
              const Pose3d& T_candidate_query_guess,
              const GuessTolerance& tolerance,
              LoopVerification& v,
              FirstEstimate& first)
{
  pcl::Correspondences& matches = first.matches;
  RigidRansacResult& ransac = first.ransac;
  matches = matchHamming(query.features, candidate.features, params.matching);
  v.num_matches = static_cast<int>(matches.size());
  first.ransac_params = params.ransac;
  first.ransac_params.min_inliers = params.min_initial_inliers;
  std::string failure;
  if (v.num_matches < params.min_initial_inliers) {
    failure = "too few matches: " + std::to_string(v.num_matches) + " < " +
              std::to_string(params.min_initial_inliers);
  }
  else {
    ransac = estimateRigidRansac(
        query.features.points, candidate.features.points, matches, first.ransac_params);
    v.num_initial_inliers = static_cast<int>(ransac.inlier_indices.size());
    v.inlier_ratio = static_cast<double>(v.num_initial_inliers) / v.num_matches;
    v.T_candidate_query = ransac.T_target_source;
    if (!ransac.success)
      failure = "RANSAC: " + ransac.message;
    else if (v.inlier_ratio < params.min_inlier_ratio)
      failure = format("inlier ratio %.2f < %.2f", v.inlier_ratio, params.min_inlier_ratio);
  }
  if (failure.empty())
    return {};
  const double gate = std::min(tolerance.translation_m, params.guess_gate_max_m);
  if (!(gate > 0.0))
    return failure;
  HammingMatchParams gated = params.matching;
  gated.ratio = 1.0;
  gated.mutual_check = false;
  gated.spatial_gate_radius_m = gate;
  matches = matchHamming(query.features, candidate.features, gated, T_candidate_query_guess);
  ransac = matches.size() >= 3 ? estimateRigidRansac(query.features.points,
                                                      candidate.features.points,
                                                      matches,
                                                      first.ransac_params)
                               : RigidRansacResult();
  if (!ransac.success)
    return failure + "; under the odometry guess: " +
           std::to_string(ransac.inlier_indices.size()) + " RANSAC inliers of " +
           std::to_string(matches.size()) + " matches";
  v.from_guess = true;
  v.num_matches = static_cast<int>(matches.size());
  v.num_initial_inliers = static_cast<int>(ransac.inlier_indices.size());
  v.inlier_ratio = static_cast<double>(v.num_initial_inliers) / v.num_matches;
  v.T_candidate_query = ransac.T_target_source;
  return {};
}

/// Step 4: guided matching from the first estimate (the ratio test over the whole scan
/// drops most true matches between distant viewpoints), then RANSAC again with the
/// paper's minimum number of inliers.
std::string
guidedEstimate(const LoopDetectorParams& params,
               const KeyFrame& query,
               const KeyFrame& candidate,
               const FirstEstimate& first,
               LoopVerification& v,
               GuidedEstimate& guided)
{
  HammingMatchParams guided_params = params.matching;
  guided_params.ratio = std::max(guided_params.ratio, 0.9);
  guided_params.spatial_gate_radius_m = params.guided_radius_m;
  if (v.from_guess) {
    // Descriptors that failed the ratio test globally fail it within the gate too.
    guided_params.ratio = 1.0;
    guided_params.mutual_check = false;
  }
  guided.matches = matchHamming(
      query.features, candidate.features, guided_params, first.ransac.T_target_source);
  v.num_guided_matches = static_cast<int>(guided.matches.size());
  RigidRansacParams final_params = params.ransac;
  const int needed = v.from_guess ? params.min_guess_inliers : params.min_inliers;
  final_params.min_inliers = needed;
  guided.ransac = static_cast<int>(guided.matches.size()) >= needed
                      ? estimateRigidRansac(query.features.points,
                                            candidate.features.points,
                                            guided.matches,
                                            final_params)
                      : RigidRansacResult();
  v.num_inliers = static_cast<int>(guided.ransac.inlier_indices.size());
  v.inlier_rmse_m = guided.ransac.inlier_rmse_m;
  if (!guided.ransac.success || v.num_inliers < needed)
    return "guided matching: " + std::to_string(v.num_inliers) + " inliers of " +
           std::to_string(v.num_guided_matches) + " matches < " + std::to_string(needed);
  v.T_candidate_query = guided.ransac.T_target_source;
  return {};
}

/// Step 5: spatial spread of the inliers: not all on one object.
std::string
checkSpread(const LoopDetectorParams& params,
            const KeyFrame& query,
            const GuidedEstimate& guided,
            LoopVerification& v)
{
  inlierSpread(query.features.points,
               guided.matches,
               guided.ransac.inlier_indices,
               params.spread_cell_size_m,
               v.inlier_cells,
               v.inlier_spread_m);
  if (v.inlier_cells < params.min_inlier_cells)
    return "inliers in " + std::to_string(v.inlier_cells) + " cells < " +
           std::to_string(params.min_inlier_cells);
  if (v.inlier_spread_m < params.min_inlier_spread_m)
    return format(
        "inlier spread %.2f m < %.2f m", v.inlier_spread_m, params.min_inlier_spread_m);
  return {};
}

/// Step 6: uniqueness: a second, different motion explaining many outliers of the
/// first RANSAC means the scene repeats (a row of equal buildings): maybe the wrong copy.
std::string
checkUniqueness(const LoopDetectorParams& params,
                const KeyFrame& query,
                const KeyFrame& candidate,
                const FirstEstimate& first,
                LoopVerification& v)
{
  if (!(params.max_second_model_ratio < 1.0))
    return {};
  const int needed = std::max(
      params.min_initial_inliers,
      static_cast<int>(std::ceil(params.max_second_model_ratio * v.num_initial_inliers)));
  pcl::Correspondences rest;
  std::size_t k = 0;
  const auto& inliers = first.ransac.inlier_indices;
  for (std::size_t m = 0; m < first.matches.size(); ++m) {
    if (k < inliers.size() && inliers[k] == static_cast<int>(m)) {
      ++k;
      continue;
    }
    rest.push_back(first.matches[m]);
  }
  if (static_cast<int>(rest.size()) < needed)
    return {};
  RigidRansacParams second_params = first.ransac_params;
  second_params.min_inliers = needed;
  const RigidRansacResult second = estimateRigidRansac(
      query.features.points, candidate.features.points, rest, second_params);
  const Pose3d delta = first.ransac.T_target_source.inverse() * second.T_target_source;
  if (second.success && (delta.translation().norm() > 2.0 || rotationDeg(delta) > 10.0)) {
    v.second_model_inliers = static_cast<int>(second.inlier_indices.size());
    return "ambiguous: a second motion has " + std::to_string(v.second_model_inliers) +
           " inliers vs " + std::to_string(v.num_initial_inliers);
  }
  return {};
}

/// Step 7: consistency with the odometry estimate (distance candidates).
std::string
checkOdometry(const Pose3d& T_candidate_query_guess,
              const GuessTolerance& tolerance,
              const LoopVerification& v)
{
  const Pose3d deviation = T_candidate_query_guess.inverse() * v.T_candidate_query;
  const double dev_m = deviation.translation().norm();
  const double dev_deg = rotationDeg(deviation);
  if ((tolerance.translation_m >= 0.0 && dev_m > tolerance.translation_m) ||
      (tolerance.rotation_deg >= 0.0 && dev_deg > tolerance.rotation_deg))
    return format("inconsistent with odometry: %.2f m / %.1f deg away (allowed "
                  "%.2f m / %.1f deg)",
                  dev_m,
                  dev_deg,
                  tolerance.translation_m,
                  tolerance.rotation_deg);
  return {};
}

/// Step 8: self-similarity: if query or candidate matches itself under a shift (a
/// street of equal blocks), the loop could be any copy; only a tight odometry guess
/// decides.
std::string
checkSelfSimilarity(const LoopDetectorParams& params,
                    const KeyFrame& query,
                    const KeyFrame& candidate,
                    const GuessTolerance& tolerance,
                    LoopVerification& v)
{
  if (!(params.max_self_similarity_ratio < 1.0))
    return {};
  RigidRansacParams self_params = params.ransac;
  self_params.min_inliers = std::max(
      params.min_initial_inliers,
      static_cast<int>(std::ceil(params.max_self_similarity_ratio * v.num_inliers)));
  for (const KeyFrame* kf : {&candidate, &query}) {
    double shift_m = 0.0;
    const int n =
        selfSimilarity(kf->features, self_params, params.retrieval_max_hamming, 3.0, shift_m);
    if (n > v.self_similar_inliers) {
      v.self_similar_inliers = n;
      v.self_similar_shift_m = shift_m;
    }
  }
  if (v.self_similar_inliers > 0 &&
      !(tolerance.translation_m >= 0.0 &&
        tolerance.translation_m < 0.5 * v.self_similar_shift_m))
    return format("repetitive scene: a %.1f m self-shift has %.0f inliers (loop %.0f) "
                  "and no odometry guess tighter than half of it",
                  v.self_similar_shift_m,
                  v.self_similar_inliers,
                  v.num_inliers);
  return {};
}

} // namespace

/// The dense check's target points of a key-frame, quantized (6 bytes a point).
std::vector<LoopDetector::DensePoint>
LoopDetector::denseTarget(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                          const LoopDetectorParams& params)
{
  const PointVector points =
      cropped(cloud, params.dense.target_voxel_size_m, params.dense_crop_radius_m);
  std::vector<DensePoint> out;
  out.reserve(points.size());
  for (const Eigen::Vector3d& p : points) {
    const Eigen::Vector3d q = (p / kDenseResolutionM).array().round();
    if ((q.array().abs() <= 32767.0).all())
      out.push_back({static_cast<std::int16_t>(q.x()),
                     static_cast<std::int16_t>(q.y()),
                     static_cast<std::int16_t>(q.z())});
  }
  return out;
}

PointVector
LoopDetector::decodeDense(const std::vector<DensePoint>& points)
{
  PointVector out;
  out.reserve(points.size());
  for (const DensePoint& q : points)
    out.emplace_back(q[0] * kDenseResolutionM, q[1] * kDenseResolutionM, q[2] * kDenseResolutionM);
  return out;
}

// ---------------------------------------------------------------- params and names

bool
LoopDetectorParams::isValid(std::string* why) const
{
  std::ostringstream r;
  auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  auto non_negative = [](double v) { return std::isfinite(v) && v >= 0.0; };
  std::string sub;
  if (!positive(search_radius_m))
    r << "search_radius_m must be finite and > 0, got " << search_radius_m;
  else if (max_distance_candidates < 0)
    r << "max_distance_candidates must be >= 0, got " << max_distance_candidates;
  else if (min_keyframe_gap < 1)
    r << "min_keyframe_gap must be >= 1, got " << min_keyframe_gap;
  else if (!non_negative(min_travel_gap_m))
    r << "min_travel_gap_m must be finite and >= 0, got " << min_travel_gap_m;
  else if (max_appearance_candidates < 0)
    r << "max_appearance_candidates must be >= 0, got " << max_appearance_candidates;
  else if (num_hash_tables < 1 || num_hash_tables > kMaxHashTables)
    r << "num_hash_tables must be in [1, " << kMaxHashTables << "], got "
      << num_hash_tables;
  else if (retrieval_max_hamming < 0 || retrieval_max_hamming > 256)
    r << "retrieval_max_hamming must be in [0, 256], got " << retrieval_max_hamming;
  else if (!(max_bucket_fraction > 0.0 && max_bucket_fraction <= 1.0))
    r << "max_bucket_fraction must be in (0, 1], got " << max_bucket_fraction;
  else if (max_bucket_size < 0)
    r << "max_bucket_size must be >= 0, got " << max_bucket_size;
  else if (min_appearance_score < 1)
    r << "min_appearance_score must be >= 1, got " << min_appearance_score;
  else if (max_verifications < 1)
    r << "max_verifications must be >= 1, got " << max_verifications;
  else if (max_accepted < 1)
    r << "max_accepted must be >= 1, got " << max_accepted;
  else if (!matching.isValid(&sub))
    r << "matching: " << sub;
  else if (!ransac.isValid(&sub))
    r << "ransac: " << sub;
  else if (min_initial_inliers < 3)
    r << "min_initial_inliers must be >= 3, got " << min_initial_inliers;
  else if (min_inliers < 3)
    r << "min_inliers must be >= 3, got " << min_inliers;
  else if (!(guess_gate_max_m >= 0.0) || !std::isfinite(guess_gate_max_m))
    r << "guess_gate_max_m must be finite and >= 0, got " << guess_gate_max_m;
  else if (min_guess_inliers < 3)
    r << "min_guess_inliers must be >= 3, got " << min_guess_inliers;
  else if (!positive(guided_radius_m))
    r << "guided_radius_m must be finite and > 0, got " << guided_radius_m;
  else if (!(rotation_bin_deg >= 0.0 && rotation_bin_deg <= 120.0))
    r << "rotation_bin_deg must be in [0, 120], got " << rotation_bin_deg;
  else if (!(min_inlier_ratio >= 0.0 && min_inlier_ratio <= 1.0))
    r << "min_inlier_ratio must be in [0, 1], got " << min_inlier_ratio;
  else if (!positive(spread_cell_size_m))
    r << "spread_cell_size_m must be finite and > 0, got " << spread_cell_size_m;
  else if (min_inlier_cells < 0)
    r << "min_inlier_cells must be >= 0, got " << min_inlier_cells;
  else if (!non_negative(min_inlier_spread_m))
    r << "min_inlier_spread_m must be finite and >= 0, got " << min_inlier_spread_m;
  else if (!(max_second_model_ratio > 0.0 && max_second_model_ratio <= 1.0))
    r << "max_second_model_ratio must be in (0, 1], got " << max_second_model_ratio;
  else if (!(max_self_similarity_ratio > 0.0 && max_self_similarity_ratio <= 1.0))
    r << "max_self_similarity_ratio must be in (0, 1], got " << max_self_similarity_ratio;
  else if (!positive(dense_crop_radius_m))
    r << "dense_crop_radius_m must be finite and > 0, got " << dense_crop_radius_m;
  else if (dense_check && !dense.isValid(&sub))
    r << "dense: " << sub;
  else if (!(min_dense_overlap >= 0.0 && min_dense_overlap <= 1.0))
    r << "min_dense_overlap must be in [0, 1], got " << min_dense_overlap;
  else if (!positive(dense_inlier_distance_m))
    r << "dense_inlier_distance_m must be finite and > 0, got "
      << dense_inlier_distance_m;
  else if (!positive(max_dense_rmse_m))
    r << "max_dense_rmse_m must be finite and > 0, got " << max_dense_rmse_m;
  else if (final_refinement && !final_refine.isValid(&sub))
    r << "final_refine: " << sub;
  else if (final_refinement && (!positive(final_max_change_m) || !positive(final_max_change_deg)))
    r << "final_max_change_m and final_max_change_deg must be > 0, got " << final_max_change_m
      << ", " << final_max_change_deg;
  else if (!non_negative(max_odometry_deviation_m))
    r << "max_odometry_deviation_m must be finite and >= 0, got "
      << max_odometry_deviation_m;
  else if (!non_negative(max_odometry_deviation_deg))
    r << "max_odometry_deviation_deg must be finite and >= 0, got "
      << max_odometry_deviation_deg;
  else if (!non_negative(odometry_deviation_per_m))
    r << "odometry_deviation_per_m must be finite and >= 0, got "
      << odometry_deviation_per_m;
  else if (!non_negative(odometry_deviation_deg_per_m))
    r << "odometry_deviation_deg_per_m must be finite and >= 0, got "
      << odometry_deviation_deg_per_m;
  const std::string reason = r.str();
  if (why)
    *why = reason;
  return reason.empty();
}

const char*
toString(LoopCandidateSource source)
{
  switch (source) {
  case LoopCandidateSource::kDistance:
    return "distance";
  case LoopCandidateSource::kAppearance:
    return "appearance";
  case LoopCandidateSource::kBoth:
    return "both";
  }
  return "unknown";
}

const char*
toString(AppearanceRetrieval retrieval)
{
  switch (retrieval) {
  case AppearanceRetrieval::kNone:
    return "none";
  case AppearanceRetrieval::kSubstringVotes:
    return "substring_votes";
  case AppearanceRetrieval::kHammingVotes:
    return "hamming_votes";
  }
  return "unknown";
}

const LoopVerification*
LoopDetection::best() const
{
  const LoopVerification* best = nullptr;
  for (const auto& v : verifications)
    if (v.accepted && (!best || v.num_inliers > best->num_inliers))
      best = &v;
  return best;
}

// ---------------------------------------------------------------- database

LoopDetector::LoopDetector(const LoopDetectorParams& params, BlobStore::Ptr dense_store)
  : params_(params)
  , dense_store_(dense_store ? std::move(dense_store) : std::make_shared<BlobStore>())
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("LoopDetector: invalid params: " + why);
}

LoopDetector::~LoopDetector() = default;

std::size_t
LoopDetector::size() const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return entries_.size();
}

std::size_t
LoopDetector::numSkipped() const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return skipped_;
}

Pose3d
LoopDetector::pose(KeyFrameId id) const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = slot_of_.find(id);
  if (it == slot_of_.end())
    throw std::invalid_argument("LoopDetector::pose: unknown key-frame id " +
                                std::to_string(id));
  return entries_[it->second].T_world_keyframe;
}

void
LoopDetector::addKeyFrame(const KeyFrame::ConstPtr& keyframe,
                          const Pose3d& T_world_keyframe)
{
  if (!keyframe)
    throw std::invalid_argument("LoopDetector::addKeyFrame: null key-frame");
  if (keyframe->features.points.size() != keyframe->features.descriptors.size())
    throw std::invalid_argument(
        "LoopDetector::addKeyFrame: key-frame " + std::to_string(keyframe->id) + " has " +
        std::to_string(keyframe->features.points.size()) + " feature points but " +
        std::to_string(keyframe->features.descriptors.size()) + " descriptors");
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (slot_of_.count(keyframe->id))
    throw std::invalid_argument("LoopDetector::addKeyFrame: key-frame id " +
                                std::to_string(keyframe->id) +
                                " is already in the database");
  Entry entry;
  entry.keyframe = keyframe;
  entry.T_world_keyframe = T_world_keyframe;
  entry.travel_m = advanceTail(*keyframe, T_world_keyframe);
  if (params_.dense_check && keyframe->cloud)
    entry.dense_target = dense_store_->putVector(denseTarget(*keyframe->cloud, params_));
  entry.first_feature = static_cast<std::uint32_t>(feature_slot_.size());
  const auto slot = static_cast<std::uint32_t>(entries_.size());
  if (params_.retrieval != AppearanceRetrieval::kNone) {
    for (const auto& d : keyframe->features.descriptors) {
      const auto g = static_cast<std::uint32_t>(feature_slot_.size());
      feature_slot_.push_back(slot);
      for (int t = 0; t < params_.num_hash_tables; ++t) {
        Bucket& bucket = buckets_[substringKey(d, t)];
        if (bucket.saturated)
          continue;
        bucket.features.push_back(g);
        // A bucket past max_bucket_size is never read again (retrieval skips buckets
        // larger than the cap, and buckets only grow), so its list is dropped. In a
        // simulated town ~60 % of the postings would land in such buckets.
        if (params_.max_bucket_size > 0 &&
            bucket.features.size() > static_cast<std::size_t>(params_.max_bucket_size)) {
          bucket.saturated = true;
          bucket.features = std::vector<std::uint32_t>();
        }
      }
    }
  }
  slot_of_.emplace(keyframe->id, entries_.size());
  entries_.push_back(std::move(entry));
}

LoopDetector::MemoryUsage
LoopDetector::memoryUsage() const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  MemoryUsage m;
  for (const Entry& e : entries_)
    (dense_store_->spilled() ? m.dense_targets_on_disk : m.dense_targets) += e.dense_target.bytes;
  m.appearance_index = feature_slot_.capacity() * sizeof(std::uint32_t);
  // unordered_map node (key, vector, next pointer, malloc header) plus its bucket slot.
  const std::size_t node_bytes =
      sizeof(std::uint32_t) + sizeof(Bucket) + 2 * sizeof(void*) + sizeof(void*);
  for (const auto& [key, bucket] : buckets_)
    m.appearance_index += node_bytes + bucket.features.capacity() * sizeof(std::uint32_t);
  return m;
}

void
LoopDetector::updatePose(KeyFrameId id, const Pose3d& T_world_keyframe)
{
  std::unique_lock<std::shared_mutex> lock(mutex_);
  const auto it = slot_of_.find(id);
  if (it == slot_of_.end())
    throw std::invalid_argument("LoopDetector::updatePose: unknown key-frame id " +
                                std::to_string(id));
  entries_[it->second].T_world_keyframe = T_world_keyframe;
}

void
LoopDetector::updatePoses(const PoseVector& T_world_by_id)
{
  std::unique_lock<std::shared_mutex> lock(mutex_);
  for (Entry& e : entries_)
    if (e.keyframe->id < T_world_by_id.size())
      e.T_world_keyframe = T_world_by_id[e.keyframe->id];
  if (tail_ && tail_->id < T_world_by_id.size())
    tail_->T_world_keyframe = T_world_by_id[tail_->id];
}

// ---------------------------------------------------------------- candidates

double
LoopDetector::travelTo(const KeyFrame& query, const Pose3d& T_world_query) const
{
  if (!tail_)
    return 0.0;
  return tail_->travel_m + stepLength(query, T_world_query, tail_->id, tail_->T_world_keyframe);
}

double
LoopDetector::advanceTail(const KeyFrame& keyframe, const Pose3d& T_world_keyframe)
{
  const double travel_m = travelTo(keyframe, T_world_keyframe);
  tail_ = Tail{keyframe.id, T_world_keyframe, travel_m};
  return travel_m;
}

void
LoopDetector::skipKeyFrame(const KeyFrame& keyframe, const Pose3d& T_world_keyframe)
{
  std::unique_lock<std::shared_mutex> lock(mutex_);
  advanceTail(keyframe, T_world_keyframe);
  ++skipped_;
}

std::optional<KeyFrameId>
LoopDetector::coveringKeyFrame(const KeyFrame& query,
                               const Pose3d& T_world_query,
                               double radius_m,
                               double angle_deg) const
{
  if (!(radius_m > 0.0) || !(angle_deg > 0.0))
    throw std::invalid_argument("LoopDetector::coveringKeyFrame: radius_m (" +
                                std::to_string(radius_m) + ") and angle_deg (" +
                                std::to_string(angle_deg) + ") must be positive");
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const std::vector<char> eligible = eligibleSlots(query, travelTo(query, T_world_query));
  std::optional<KeyFrameId> best;
  double best_distance = radius_m;
  for (std::size_t s = 0; s < entries_.size(); ++s) {
    if (!eligible[s])
      continue;
    const Pose3d& T = entries_[s].T_world_keyframe;
    const double d = (T.translation() - T_world_query.translation()).norm();
    if (d > best_distance)
      continue;
    if (rotationDeg(T.inverse() * T_world_query) > angle_deg)
      continue;
    best_distance = d;
    best = entries_[s].keyframe->id;
  }
  return best;
}

std::vector<char>
LoopDetector::eligibleSlots(const KeyFrame& query, double query_travel_m) const
{
  std::vector<char> eligible(entries_.size(), 0);
  for (std::size_t s = 0; s < entries_.size(); ++s) {
    const auto gap = std::abs(static_cast<std::int64_t>(query.id) -
                              static_cast<std::int64_t>(entries_[s].keyframe->id));
    eligible[s] =
        gap >= params_.min_keyframe_gap &&
        std::abs(query_travel_m - entries_[s].travel_m) >= params_.min_travel_gap_m;
  }
  return eligible;
}

void
LoopDetector::scoreAppearance(const KeyFrame& query,
                              const std::vector<char>& eligible,
                              std::vector<double>& votes) const
{
  votes.assign(entries_.size(), 0.0);
  if (params_.retrieval == AppearanceRetrieval::kNone || feature_slot_.empty())
    return;
  const std::size_t total = feature_slot_.size();
  std::size_t max_bucket = std::max<std::size_t>(
      64,
      static_cast<std::size_t>(params_.max_bucket_fraction * static_cast<double>(total)));
  if (params_.max_bucket_size > 0)
    max_bucket = std::min<std::size_t>(max_bucket, params_.max_bucket_size);

  if (params_.retrieval == AppearanceRetrieval::kSubstringVotes) {
    // Inverted index: each shared substring votes with weight log(N / n_bucket).
    for (const auto& q : query.features.descriptors)
      for (int t = 0; t < params_.num_hash_tables; ++t) {
        const auto it = buckets_.find(substringKey(q, t));
        if (it == buckets_.end() || it->second.saturated ||
            it->second.features.size() > max_bucket)
          continue;
        const double w = std::log(static_cast<double>(total) / it->second.features.size());
        for (const std::uint32_t g : it->second.features)
          if (eligible[feature_slot_[g]])
            votes[feature_slot_[g]] += w;
      }
    return;
  }

  // Multi-index hashing: a database descriptor within r bits of q shares at least one
  // of the m substrings exactly when r < m (pigeonhole), and most of them in practice
  // for larger r; its full distance then decides. One vote per (query feature,
  // key-frame). A vote also carries the rotation it implies (difference of the ORB
  // angles): the votes of a real revisit pile up at one relative yaw.
  const int bins =
      params_.rotation_bin_deg > 0.0
          ? std::max(1, static_cast<int>(std::lround(360.0 / params_.rotation_bin_deg)))
          : 1;
  std::vector<float> histogram(entries_.size() * bins, 0.0f);
  std::vector<std::uint32_t> seen(total, 0);
  struct Vote
  {
    std::uint32_t slot;
    int distance;
    int bin;
  };
  std::vector<Vote> found;
  const auto& descriptors = query.features.descriptors;
  for (std::size_t i = 0; i < descriptors.size(); ++i) {
    const auto stamp = static_cast<std::uint32_t>(i + 1);
    found.clear();
    for (int t = 0; t < params_.num_hash_tables; ++t) {
      const auto it = buckets_.find(substringKey(descriptors[i], t));
      if (it == buckets_.end() || it->second.saturated ||
          it->second.features.size() > max_bucket)
        continue;
      for (const std::uint32_t g : it->second.features) {
        if (seen[g] == stamp)
          continue;
        seen[g] = stamp;
        const std::uint32_t slot = feature_slot_[g];
        if (!eligible[slot])
          continue;
        const Entry& e = entries_[slot];
        const std::size_t j = g - e.first_feature;
        const int d =
            hammingDistance(descriptors[i], e.keyframe->features.descriptors[j]);
        if (d > params_.retrieval_max_hamming)
          continue;
        double dyaw =
            e.keyframe->features.points[j].angle_deg - query.features.points[i].angle_deg;
        dyaw -= 360.0 * std::floor(dyaw / 360.0);
        found.push_back({slot, d, static_cast<int>(dyaw / 360.0 * bins) % bins});
      }
    }
    // One vote per (query feature, key-frame): its nearest descriptor there.
    std::sort(found.begin(), found.end(), [](const Vote& a, const Vote& b) {
      return a.slot < b.slot || (a.slot == b.slot && a.distance < b.distance);
    });
    for (std::size_t k = 0; k < found.size(); ++k)
      if (k == 0 || found[k].slot != found[k - 1].slot)
        histogram[found[k].slot * bins + found[k].bin] += 1.0f;
  }
  for (std::size_t s = 0; s < entries_.size(); ++s) {
    const float* h = &histogram[s * bins];
    if (bins == 1) {
      votes[s] = h[0];
      continue;
    }
    float best = 0.0f;
    for (int b = 0; b < bins; ++b)
      best = std::max(best, h[(b + bins - 1) % bins] + h[b] + h[(b + 1) % bins]);
    votes[s] = best;
  }
}

std::vector<std::pair<KeyFrameId, int>>
LoopDetector::rankByAppearance(const KeyFrame& query, const Pose3d& T_world_query) const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<std::pair<KeyFrameId, int>> ranking;
  if (params_.retrieval == AppearanceRetrieval::kNone || entries_.empty())
    return ranking;
  const auto eligible = eligibleSlots(query, travelTo(query, T_world_query));
  std::vector<double> votes;
  scoreAppearance(query, eligible, votes);
  std::vector<std::pair<double, std::size_t>> order;
  for (std::size_t s = 0; s < entries_.size(); ++s)
    if (eligible[s] && votes[s] > 0.0)
      order.emplace_back(votes[s] / std::sqrt(std::max<std::size_t>(
                                        1, entries_[s].keyframe->features.size())),
                         s);
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) {
    return a.first > b.first;
  });
  for (const auto& [score, s] : order)
    ranking.emplace_back(entries_[s].keyframe->id,
                         static_cast<int>(std::lround(votes[s])));
  return ranking;
}

LoopDetection
LoopDetector::detect(const KeyFrame& query, const Pose3d& T_world_query) const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  LoopDetection out;
  if (entries_.empty())
    return out;
  const auto t0 = Clock::now();
  const double query_travel_m = travelTo(query, T_world_query);
  const auto eligible = eligibleSlots(query, query_travel_m);

  // 1. The paper: key-frames near the query's current estimate, nearest first.
  std::vector<std::pair<double, std::size_t>> near;
  for (std::size_t s = 0; s < entries_.size(); ++s) {
    if (!eligible[s])
      continue;
    const double d =
        (entries_[s].T_world_keyframe.translation() - T_world_query.translation()).norm();
    if (d <= params_.search_radius_m)
      near.emplace_back(d, s);
  }
  std::sort(near.begin(), near.end());
  near.resize(std::min<std::size_t>(near.size(), params_.max_distance_candidates));

  // 2. Beyond the paper: the top-k key-frames by normalised appearance score.
  std::vector<double> votes;
  scoreAppearance(query, eligible, votes);
  std::vector<std::pair<double, std::size_t>> alike;
  for (std::size_t s = 0; s < entries_.size(); ++s)
    if (eligible[s] && votes[s] >= params_.min_appearance_score)
      alike.emplace_back(votes[s] / std::sqrt(std::max<std::size_t>(
                                        1, entries_[s].keyframe->features.size())),
                         s);
  std::sort(alike.begin(), alike.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
  alike.resize(std::min<std::size_t>(alike.size(), params_.max_appearance_candidates));

  // 3. Merge; verify the most promising first: found by both, then by votes, nearest.
  std::vector<std::size_t> slots;
  for (const auto& [d, s] : near)
    slots.push_back(s);
  for (const auto& [score, s] : alike)
    if (std::find(slots.begin(), slots.end(), s) == slots.end())
      slots.push_back(s);
  for (const std::size_t s : slots) {
    LoopCandidate c;
    c.keyframe = entries_[s].keyframe->id;
    c.distance_m =
        (entries_[s].T_world_keyframe.translation() - T_world_query.translation()).norm();
    c.appearance_score = static_cast<int>(std::lround(votes[s]));
    const bool by_distance = std::any_of(
        near.begin(), near.end(), [s](const auto& n) { return n.second == s; });
    const bool by_appearance = std::any_of(
        alike.begin(), alike.end(), [s](const auto& a) { return a.second == s; });
    c.source = by_distance && by_appearance ? LoopCandidateSource::kBoth
               : by_distance                ? LoopCandidateSource::kDistance
                                            : LoopCandidateSource::kAppearance;
    out.candidates.push_back(c);
  }
  std::stable_sort(out.candidates.begin(),
                   out.candidates.end(),
                   [](const LoopCandidate& a, const LoopCandidate& b) {
                     const bool a_both = a.source == LoopCandidateSource::kBoth;
                     const bool b_both = b.source == LoopCandidateSource::kBoth;
                     if (a_both != b_both)
                       return a_both;
                     if (a.appearance_score != b.appearance_score)
                       return a.appearance_score > b.appearance_score;
                     return a.distance_m < b.distance_m;
                   });
  out.retrieval_ms = msSince(t0);

  // 4. Verify. Candidates found by distance only are checked against odometry, with a
  // tolerance that grows with the distance travelled since them; those that also look
  // alike, or only look alike, are not (the drift may be larger than the tolerance).
  const auto t1 = Clock::now();
  const bool scored = params_.retrieval != AppearanceRetrieval::kNone;
  for (const LoopCandidate& c : out.candidates) {
    if (static_cast<int>(out.verifications.size()) >= params_.max_verifications ||
        out.num_accepted >= params_.max_accepted)
      break;
    const Entry& e = entries_[slot_of_.at(c.keyframe)];
    if (scored && c.appearance_score < params_.min_appearance_score) {
      // Fewer look-alike features than a verification needs: not worth the matching.
      LoopVerification v;
      v.query = query.id;
      v.candidate = c.keyframe;
      v.reason = "appearance score " + std::to_string(c.appearance_score) + " < " +
                 std::to_string(params_.min_appearance_score) + ": not verified";
      out.verifications.push_back(v);
      continue;
    }
    GuessTolerance tolerance;
    if (c.source == LoopCandidateSource::kDistance) {
      const double travel = std::abs(query_travel_m - e.travel_m);
      tolerance.translation_m =
          params_.max_odometry_deviation_m + params_.odometry_deviation_per_m * travel;
      tolerance.rotation_deg = params_.max_odometry_deviation_deg +
                               params_.odometry_deviation_deg_per_m * travel;
    }
    const Pose3d guess = e.T_world_keyframe.inverse() * T_world_query;
    const std::vector<DensePoint> dense_target =
        dense_store_->getVector<DensePoint>(e.dense_target);
    out.verifications.push_back(
        verifyPair(query, *e.keyframe, guess, tolerance, &dense_target));
    out.num_accepted += out.verifications.back().accepted;
  }
  out.num_rejected = static_cast<int>(out.verifications.size()) - out.num_accepted;
  out.verify_ms = msSince(t1);
  return out;
}

void
LoopDetector::refineAccepted(const KeyFrame& query,
                             const PointToPlaneTarget& target,
                             LoopVerification& v) const
{
  if (!params_.final_refinement || !query.cloud)
    return;
  PointToPlaneResult r;
  try {
    r = refinePointToPlane(*query.cloud, target, v.T_candidate_query, params_.final_refine);
  } catch (const std::invalid_argument&) {
    return;
  }
  if (!r.success)
    return;
  const Pose3d delta = v.T_candidate_query.inverse() * r.T_target_source;
  const double change_m = delta.translation().norm();
  const double change_deg = rotationDeg(delta);
  if (change_m > params_.final_max_change_m || change_deg > params_.final_max_change_deg)
    return;
  v.T_candidate_query = r.T_target_source;
  v.refined = true;
  v.refinement_change_m = change_m;
  v.refinement_change_deg = change_deg;
}

// ---------------------------------------------------------------- verification

LoopVerification
LoopDetector::verify(const KeyFrame& query,
                     const KeyFrame& candidate,
                     const Pose3d& T_candidate_query_guess) const
{
  GuessTolerance tolerance;
  tolerance.translation_m = params_.max_odometry_deviation_m;
  tolerance.rotation_deg = params_.max_odometry_deviation_deg;
  return verify(query, candidate, T_candidate_query_guess, tolerance);
}

LoopVerification
LoopDetector::verify(const KeyFrame& query,
                     const KeyFrame& candidate,
                     const Pose3d& T_candidate_query_guess,
                     const GuessTolerance& tolerance) const
{
  return verifyPair(query, candidate, T_candidate_query_guess, tolerance, nullptr);
}

LoopVerification
LoopDetector::verifyPair(const KeyFrame& query,
                         const KeyFrame& candidate,
                         const Pose3d& T_candidate_query_guess,
                         const GuessTolerance& tolerance,
                         const std::vector<DensePoint>* candidate_dense) const
{
  const auto t0 = Clock::now();
  LoopVerification v;
  v.query = query.id;
  v.candidate = candidate.id;
  auto reject = [&](const std::string& why) {
    v.accepted = false;
    v.reason = why;
    v.verify_ms = msSince(t0);
    return v;
  };
  if (static_cast<int>(query.features.size()) < params_.min_inliers ||
      static_cast<int>(candidate.features.size()) < params_.min_inliers)
    return reject("too few features: " + std::to_string(query.features.size()) + " / " +
                  std::to_string(candidate.features.size()));

  // Each step either passes or says why the pair is rejected.
  FirstEstimate first;
  GuidedEstimate guided;
  std::string why = firstEstimate(params_, query, candidate, T_candidate_query_guess,
                                  tolerance, v, first);
  if (why.empty())
    why = guidedEstimate(params_, query, candidate, first, v, guided);
  if (why.empty())
    why = checkSpread(params_, query, guided, v);
  if (why.empty())
    why = checkUniqueness(params_, query, candidate, first, v);
  if (why.empty())
    why = checkOdometry(T_candidate_query_guess, tolerance, v);
  if (why.empty())
    why = checkSelfSimilarity(params_, query, candidate, tolerance, v);
  if (why.empty() && params_.dense_check)
    why = denseCheck(query, candidate, candidate_dense, v);
  if (!why.empty())
    return reject(why);

  v.accepted = true;
  v.verify_ms = msSince(t0);
  v.reason =
      format("accepted: %.0f inliers (ratio %.2f), dense overlap %.2f, rmse %.3f m",
             v.num_inliers,
             v.inlier_ratio,
             v.dense_overlap,
             v.dense_rmse_m);
  return v;
}

std::string
LoopDetector::denseCheck(const KeyFrame& query,
                         const KeyFrame& candidate,
                         const std::vector<DensePoint>* candidate_dense,
                         LoopVerification& v) const
{
  // 9. Dense check: point-to-plane refinement of the query's planar points on the
  // candidate's, then the share of query structure (walls, not ground) that fits.
  if (!query.cloud || (!candidate.cloud && !(candidate_dense && !candidate_dense->empty())))
    return "dense check: a key-frame has no cloud";
  const PointToPlaneParams& dp = params_.dense;
  PointToPlaneTarget target, query_planes;
  PointToPlaneParams query_params = dp;
  query_params.target_voxel_size_m = dp.source_voxel_size_m;
  try {
    target.build(candidate_dense && !candidate_dense->empty()
                     ? decodeDense(*candidate_dense)
                     : decodeDense(denseTarget(*candidate.cloud, params_)),
                 dp);
    query_planes.build(
        cropped(*query.cloud, query_params.target_voxel_size_m, params_.dense_crop_radius_m),
        query_params);
  } catch (const std::invalid_argument& e) {
    return std::string("dense check: ") + e.what();
  }
  if (target.empty() || query_planes.empty())
    return "dense check: no planar points";
  const PointToPlaneResult refined =
      refinePointToPlane(query_planes.points(), target, v.T_candidate_query, dp);
  if (!refined.success)
    return "dense check: " + refined.message;
  const Pose3d& T = refined.T_target_source;
  int structure = 0, paired = 0;
  double sum_sq = 0.0;
  const double cos_normal = std::cos(30.0 / kDegPerRad);
  for (std::size_t i = 0; i < query_planes.size(); ++i) {
    const Eigen::Vector3d& n = query_planes.normals()[i];
    if (std::abs(n.z()) > 0.7) // ground, roofs: agree under any planar motion
      continue;
    ++structure;
    const Eigen::Vector3d p = T * query_planes.points()[i];
    const Eigen::Vector3d n_t = T.linear() * n;
    Eigen::Vector3d q, n_q;
    if (!target.nearest(p, 2.0 * params_.dense_inlier_distance_m, q, n_q))
      continue;
    const double r = n_q.dot(p - q);
    if (std::abs(n_q.dot(n_t)) < cos_normal || std::abs(r) > params_.dense_inlier_distance_m)
      continue;
    ++paired;
    sum_sq += r * r;
  }
  v.dense_overlap = structure > 0 ? static_cast<double>(paired) / structure : 0.0;
  v.dense_rmse_m = paired > 0 ? std::sqrt(sum_sq / paired) : 0.0;
  if (structure == 0 || v.dense_overlap < params_.min_dense_overlap)
    return format("dense overlap %.2f < %.2f (%.0f structure points)",
                  v.dense_overlap,
                  params_.min_dense_overlap,
                  structure);
  if (v.dense_rmse_m > params_.max_dense_rmse_m)
    return format("dense rmse %.3f m > %.3f m", v.dense_rmse_m, params_.max_dense_rmse_m);
  v.T_candidate_query = T;
  refineAccepted(query, target, v);
  return {};
}

} // namespace rast
} // namespace pcl
