#pragma once
/// \file hamming_correspondence_estimation.h
/// \brief HammingCorrespondenceEstimation: matchHamming (hamming_matching.h) as a PCL
/// correspondence estimator on ORBSignature256 clouds.
/// \ingroup registration

#include <pcl/registration/hamming_matching.h>

#include <pcl/correspondence.h>
#include <pcl/registration/correspondence_estimation.h>

#include <Eigen/Geometry>

#include <limits>
#include <memory>
#include <string>

namespace pcl {
namespace rast {

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
