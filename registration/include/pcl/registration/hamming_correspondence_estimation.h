#pragma once
/// \file hamming_correspondence_estimation.h
/// \brief Source -> target matching of ORB descriptors by Hamming distance, with an
/// optional spatial gate (motion prior), mutual check and Lowe's ratio test.
/// \ingroup registration

#include <pcl/features/raster_feature_types.h>

#include <pcl/correspondence.h>
#include <pcl/registration/correspondence_estimation.h>

#include <Eigen/Geometry>

#include <limits>
#include <memory>
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
  bool
  isValid(std::string* why = nullptr) const;
};

/// \brief Brute-force Hamming matching of source to target features.
/// \param[in] source features of the scan to align
/// \param[in] target features of the reference scan
/// \param[in] params matching parameters
/// \param[in] T_target_source_guess initial guess, used only by the spatial gate
/// \return one correspondence per accepted source feature: index_query = source index,
///   index_match = target index, distance = Hamming distance (bits); sorted by index_query
/// \param[out] nearest if given: from the same distances, every source feature's nearest
///   target within max_hamming_distance and the gate, without ratio test or mutual check
///   (what params with ratio 1 and no mutual check would return)
/// \throws std::invalid_argument on invalid params or a set whose points and
///   descriptors differ in number
pcl::Correspondences
matchHamming(const RasterFeatureSet& source,
             const RasterFeatureSet& target,
             const HammingMatchParams& params = HammingMatchParams(),
             const Eigen::Isometry3d& T_target_source_guess = Eigen::Isometry3d::Identity(),
             pcl::Correspondences* nearest = nullptr);

/// \brief matchHamming() as a PCL correspondence estimator on ORBSignature256 clouds,
/// so it plugs into PCL's registration classes (e.g. before
/// pcl::registration::CorrespondenceRejectorSampleConsensus):
/// \code
/// pcl::registration::CorrespondenceEstimationBase<ORBSignature256, ORBSignature256>::Ptr
///     estimation(new pcl::rast::HammingCorrespondenceEstimation);
/// estimation->setInputSource(source_features);
/// estimation->setInputTarget(target_features);
/// pcl::Correspondences matches;
/// estimation->determineCorrespondences(matches);
/// \endcode
/// Distances are in descriptor space: Correspondence::distance is the Hamming distance
/// (bits), and the max_distance argument tightens params.max_hamming_distance.
/// determineCorrespondences applies the ratio test and the mutual check as the params
/// say; determineReciprocalCorrespondences always applies the mutual check. Indices
/// given to setIndices (source) and setIndicesTarget are honoured; correspondence
/// indices refer to the full clouds. No k-d tree is built.
/// \ingroup registration
class HammingCorrespondenceEstimation
: public pcl::registration::CorrespondenceEstimationBase<ORBSignature256, ORBSignature256>
{
public:
  using Base =
      pcl::registration::CorrespondenceEstimationBase<ORBSignature256, ORBSignature256>;
  using Ptr = std::shared_ptr<HammingCorrespondenceEstimation>;
  using ConstPtr = std::shared_ptr<const HammingCorrespondenceEstimation>;

  /// \throws std::invalid_argument when params are invalid
  explicit HammingCorrespondenceEstimation(const HammingMatchParams& params = HammingMatchParams());

  /// \throws std::invalid_argument when params are invalid
  void
  setParams(const HammingMatchParams& params);
  const HammingMatchParams&
  getParams() const
  {
    return params_;
  }
  /// \brief Initial T_target_source, used by the spatial gate only.
  void
  setInitialGuess(const Eigen::Isometry3d& T_target_source)
  {
    T_target_source_guess_ = T_target_source;
  }

  /// \brief Match the source to the target (see the class comment).
  /// \throws std::invalid_argument when an input is missing
  void
  determineCorrespondences(pcl::Correspondences& correspondences,
                           double max_distance = std::numeric_limits<double>::max()) override;

  /// \brief As determineCorrespondences, with the mutual check on.
  void
  determineReciprocalCorrespondences(
      pcl::Correspondences& correspondences,
      double max_distance = std::numeric_limits<double>::max()) override;

  Base::Ptr
  clone() const override
  {
    return std::make_shared<HammingCorrespondenceEstimation>(*this);
  }

private:
  void
  match(pcl::Correspondences& correspondences, double max_distance, bool mutual);

  HammingMatchParams params_;
  Eigen::Isometry3d T_target_source_guess_ = Eigen::Isometry3d::Identity();
};

} // namespace rast
} // namespace pcl
