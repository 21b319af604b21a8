/// \file hamming_correspondence_estimation.cpp
/// \brief Brute-force ORB matching: one pass over all (source, target) pairs keeps the
/// best and second-best target of each source and the best source of each target.

#include <pcl/registration/hamming_correspondence_estimation.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <vector>

namespace pcl {
namespace rast {

bool
HammingMatchParams::isValid(std::string* why) const
{
  std::string reason;
  if (max_hamming_distance < 0 || max_hamming_distance > 256)
    reason = "max_hamming_distance must be in [0, 256], got " +
             std::to_string(max_hamming_distance);
  else if (!(ratio > 0.0 && ratio <= 1.0))
    reason = "ratio must be in (0, 1], got " + std::to_string(ratio);
  else if (!(spatial_gate_radius_m >= 0.0) || !std::isfinite(spatial_gate_radius_m))
    reason = "spatial_gate_radius_m must be finite and >= 0, got " +
             std::to_string(spatial_gate_radius_m);
  if (why)
    *why = reason;
  return reason.empty();
}

namespace {

void
checkFeatureSet(const RasterFeatureSet& set, const char* name)
{
  if (set.points.size() != set.descriptors.size())
    throw std::invalid_argument(std::string("matchHamming: ") + name + " has " +
                                std::to_string(set.points.size()) + " points but " +
                                std::to_string(set.descriptors.size()) + " descriptors");
}

/// Hamming distances of one descriptor to all of \a targets (the 256-bit XOR popcount
/// of hammingDistance, written out so that the compiler can use POPCNT where present).
template <typename Popcount>
inline void
distanceRow(const OrbDescriptor& a,
            const std::vector<OrbDescriptor>& targets,
            int* out,
            Popcount popcount)
{
  std::uint64_t wa[4];
  __builtin_memcpy(wa, a.data(), 32);
  for (std::size_t j = 0; j < targets.size(); ++j) {
    std::uint64_t wb[4];
    __builtin_memcpy(wb, targets[j].data(), 32);
    out[j] = popcount(wa[0] ^ wb[0]) + popcount(wa[1] ^ wb[1]) + popcount(wa[2] ^ wb[2]) +
             popcount(wa[3] ^ wb[3]);
  }
}

void
distanceRowPortable(const OrbDescriptor& a, const std::vector<OrbDescriptor>& targets, int* out)
{
  for (std::size_t j = 0; j < targets.size(); ++j)
    out[j] = hammingDistance(a, targets[j]);
}

#if defined(__GNUC__) && (defined(__x86_64__) || defined(__i386__))
/// The same with the POPCNT instruction, compiled for it through a function attribute
/// only (the binaries stay baseline x86-64) and called when the CPU has it.
__attribute__((target("popcnt"))) void
distanceRowPopcnt(const OrbDescriptor& a, const std::vector<OrbDescriptor>& targets, int* out)
{
  distanceRow(a, targets, out,
              [](std::uint64_t x) { return static_cast<int>(__builtin_popcountll(x)); });
}

using DistanceRowFn = void (*)(const OrbDescriptor&, const std::vector<OrbDescriptor>&, int*);

DistanceRowFn
selectDistanceRow()
{
  __builtin_cpu_init();
  return __builtin_cpu_supports("popcnt") ? &distanceRowPopcnt : &distanceRowPortable;
}
#endif

} // namespace

pcl::Correspondences
matchHamming(const RasterFeatureSet& source,
             const RasterFeatureSet& target,
             const HammingMatchParams& params,
             const Eigen::Isometry3d& T_target_source_guess,
             pcl::Correspondences* nearest)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("matchHamming: invalid params: " + why);
  checkFeatureSet(source, "source");
  checkFeatureSet(target, "target");

  constexpr int kNone = std::numeric_limits<int>::max();
  const std::size_t n_source = source.size();
  const std::size_t n_target = target.size();
  std::vector<int> best_target(n_source, -1), best_distance(n_source, kNone),
      second_distance(n_source, kNone);
  std::vector<int> best_source(n_target, -1), best_source_distance(n_target, kNone);

  const bool gated = params.spatial_gate_radius_m > 0.0;
  const float gate_sq = static_cast<float>(params.spatial_gate_radius_m *
                                           params.spatial_gate_radius_m);
  const Eigen::Isometry3f T = T_target_source_guess.cast<float>();

#if defined(__GNUC__) && (defined(__x86_64__) || defined(__i386__))
  static const DistanceRowFn distance_row = selectDistanceRow();
#else
  const auto distance_row = &distanceRowPortable;
#endif
  std::vector<int> row(n_target);
  for (std::size_t i = 0; i < n_source; ++i) {
    const Eigen::Vector3f p_in_target = T * source.points[i].getVector3fMap();
    distance_row(source.descriptors[i], target.descriptors, row.data());
    for (std::size_t j = 0; j < n_target; ++j) {
      if (gated &&
          (target.points[j].getVector3fMap() - p_in_target).squaredNorm() > gate_sq)
        continue;
      const int d = row[j];
      if (d < best_distance[i]) {
        second_distance[i] = best_distance[i];
        best_distance[i] = d;
        best_target[i] = static_cast<int>(j);
      }
      else if (d < second_distance[i])
        second_distance[i] = d;
      if (d < best_source_distance[j]) {
        best_source_distance[j] = d;
        best_source[j] = static_cast<int>(i);
      }
    }
  }

  pcl::Correspondences correspondences;
  if (nearest)
    nearest->clear();
  for (std::size_t i = 0; i < n_source; ++i) {
    const int j = best_target[i];
    if (j < 0 || best_distance[i] > params.max_hamming_distance)
      continue;
    if (nearest)
      nearest->emplace_back(static_cast<int>(i), j, static_cast<float>(best_distance[i]));
    if (params.ratio < 1.0 && second_distance[i] != kNone &&
        !(best_distance[i] < params.ratio * second_distance[i]))
      continue;
    if (params.mutual_check && best_source[j] != static_cast<int>(i))
      continue;
    correspondences.emplace_back(static_cast<int>(i), j, static_cast<float>(best_distance[i]));
  }
  return correspondences;
}

HammingCorrespondenceEstimation::HammingCorrespondenceEstimation(const HammingMatchParams& params)
{
  setParams(params);
}

void
HammingCorrespondenceEstimation::setParams(const HammingMatchParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("HammingCorrespondenceEstimation::setParams: " + why);
  params_ = params;
}

void
HammingCorrespondenceEstimation::determineCorrespondences(pcl::Correspondences& correspondences,
                                                          double max_distance)
{
  match(correspondences, max_distance, params_.mutual_check);
}

void
HammingCorrespondenceEstimation::determineReciprocalCorrespondences(
    pcl::Correspondences& correspondences, double max_distance)
{
  match(correspondences, max_distance, true);
}

void
HammingCorrespondenceEstimation::match(pcl::Correspondences& correspondences,
                                       double max_distance,
                                       bool mutual)
{
  if (!input_ || !target_)
    throw std::invalid_argument(
        std::string("HammingCorrespondenceEstimation::determineCorrespondences: no input ") +
        (input_ ? "target" : "source") + " set");
  // The clouds (or their indexed subsets) as feature sets; indices map back.
  auto gather = [](const pcl::PointCloud<ORBSignature256>& cloud,
                   const pcl::IndicesPtr& indices, RasterFeatureSet& set) {
    if (!indices) {
      fromSignatureCloud(cloud, set);
      return;
    }
    pcl::PointCloud<ORBSignature256> subset;
    for (const auto i : *indices) {
      if (i < 0 || static_cast<std::size_t>(i) >= cloud.size())
        throw std::out_of_range("HammingCorrespondenceEstimation: index " + std::to_string(i) +
                                " outside the cloud of " + std::to_string(cloud.size()) +
                                " features");
      subset.push_back(cloud[i]);
    }
    fromSignatureCloud(subset, set);
  };
  const bool source_indexed = indices_ && indices_->size() != input_->size();
  RasterFeatureSet source, target;
  gather(*input_, source_indexed ? indices_ : nullptr, source);
  gather(*target_, target_indices_, target);

  HammingMatchParams params = params_;
  params.mutual_check = mutual;
  if (max_distance < params.max_hamming_distance)
    params.max_hamming_distance = std::max(0, static_cast<int>(std::floor(max_distance)));
  correspondences = matchHamming(source, target, params, T_target_source_guess_);
  for (auto& c : correspondences) {
    if (source_indexed)
      c.index_query = (*indices_)[c.index_query];
    if (target_indices_)
      c.index_match = (*target_indices_)[c.index_match];
  }
}

} // namespace rast
} // namespace pcl

// The base class builds k-d trees over the feature clouds on construction (never used
// here); PCL compiles its search classes for its own point types only.
#include <pcl/impl/instantiate.hpp>
#include <pcl/impl/pcl_base.hpp>
#include <pcl/kdtree/impl/kdtree_flann.hpp>
#include <pcl/search/impl/kdtree.hpp>
#include <pcl/search/impl/search.hpp>

PCL_INSTANTIATE(PCLBase, (pcl::rast::ORBSignature256))
PCL_INSTANTIATE(Search, (pcl::rast::ORBSignature256))
PCL_INSTANTIATE(KdTree, (pcl::rast::ORBSignature256))
PCL_INSTANTIATE(KdTreeFLANN, (pcl::rast::ORBSignature256))
