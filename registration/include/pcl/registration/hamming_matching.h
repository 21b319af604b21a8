#pragma once
/// \file hamming_matching.h
/// \brief Source -> target matching of ORB descriptors by Hamming distance, with an
/// optional spatial gate (motion prior), mutual check and Lowe's ratio test. The same
/// as a PCL correspondence estimator: hamming_correspondence_estimation.h. This header
/// stays light (no PCL registration header) for the SLAM's many users of it.
/// \ingroup registration

#include <Eigen/Geometry>
#include <pcl/correspondence.h>
#include <pcl/features/raster_feature_types.h>
#include <string>

namespace pcl {
namespace rast {

/// \brief Parameters of Hamming matching.
struct HammingMatchParams
{
  /// Largest accepted Hamming distance of a match (bits, 0..256).
  int max_hamming_distance = 64;
  /// Lowe's ratio test: keep a match only if best < ratio * second best (0, 1];
  /// 1.0 disables the test. Without a second candidate the match is kept.
  double ratio = 0.8;
  /// Keep source i -> target j only if i is also the best source for j.
  bool mutual_check = true;
  /// > 0: candidates are only the target features within this distance of
  /// T_target_source_guess * p_source (metres); 0 disables the gate.
  double spatial_gate_radius_m = 0.0;

  /// \brief True when all values are in range; otherwise says why in *why (if given).
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Brute-force Hamming matching of source to target features.
/// \param[in] source features of the scan to align
/// \param[in] target features of the reference scan
/// \param[in] params matching parameters
/// \param[in] T_target_source_guess initial guess, used only by the spatial gate
/// \return one correspondence per accepted source feature: index_query = source index,
///   index_match = target index, distance = Hamming distance (bits); sorted by
///   index_query
/// \param[out] nearest if given: from the same distances, every source feature's nearest
///   target within max_hamming_distance and the gate, without ratio test or mutual check
///   (what params with ratio 1 and no mutual check would return)
/// \throws std::invalid_argument on invalid params or a set whose points and
///   descriptors differ in number
pcl::Correspondences matchHamming(
    const RasterFeatureSet& source,
    const RasterFeatureSet& target,
    const HammingMatchParams& params = HammingMatchParams(),
    const Eigen::Isometry3d& T_target_source_guess = Eigen::Isometry3d::Identity(),
    pcl::Correspondences* nearest = nullptr);

} // namespace rast
} // namespace pcl
