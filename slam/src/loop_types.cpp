/// \file loop_types.cpp
/// \brief Validation of LoopDetectorParams and the names of the loop-closing enums.

#include <pcl/slam/keyframe_database.h>
#include <pcl/slam/loop_types.h>

#include <cmath>
#include <sstream>

namespace pcl {
namespace rast {

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
  else if (num_hash_tables < 1 || num_hash_tables > KeyFrameDatabase::kMaxHashTables)
    r << "num_hash_tables must be in [1, " << KeyFrameDatabase::kMaxHashTables << "], got "
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
  else if (!(tentative_dense_overlap < 0.0 ||
             tentative_dense_overlap <= min_dense_overlap))
    r << "tentative_dense_overlap must be negative (none) or at most min_dense_overlap ("
      << min_dense_overlap << "), got " << tentative_dense_overlap;
  else if (min_dense_structure < 0)
    r << "min_dense_structure must be >= 0, got " << min_dense_structure;
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

} // namespace rast
} // namespace pcl
