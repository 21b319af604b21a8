/// \file umeyama_estimation.cpp
/// \brief Closed-form least-squares rigid transform (eq. 4 of the paper), after
/// Umeyama, "Least-squares estimation of transformation parameters between two point
/// patterns", PAMI 1991, without the scale.

#include <pcl/registration/umeyama_estimation.h>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include <cmath>
#include <stdexcept>
#include <string>

namespace pcl {
namespace rast {

RigidTransformEstimate
estimateRigidTransform(const Eigen::Matrix3Xd& source,
                       const Eigen::Matrix3Xd& target,
                       const Eigen::VectorXd& weights)
{
  const Eigen::Index n = source.cols();
  if (target.cols() != n)
    throw std::invalid_argument("estimateRigidTransform: " + std::to_string(n) +
                                " source points but " + std::to_string(target.cols()) +
                                " target points");
  if (n < 3)
    throw std::invalid_argument("estimateRigidTransform: need at least 3 point pairs, got " +
                                std::to_string(n));
  Eigen::VectorXd w = weights.size() == 0 ? Eigen::VectorXd::Ones(n) : weights;
  if (w.size() != n)
    throw std::invalid_argument("estimateRigidTransform: " + std::to_string(w.size()) +
                                " weights for " + std::to_string(n) + " point pairs");
  if (!w.allFinite() || (w.array() < 0.0).any() || w.sum() <= 0.0)
    throw std::invalid_argument(
        "estimateRigidTransform: weights must be finite, >= 0 and not all 0");
  if (!source.allFinite() || !target.allFinite())
    throw std::invalid_argument("estimateRigidTransform: non-finite point coordinates");
  w /= w.sum();

  // Weighted centroids, then the cross-covariance of the centred sets.
  const Eigen::Vector3d mu_source = source * w;
  const Eigen::Vector3d mu_target = target * w;
  const Eigen::Matrix3Xd source_c = source.colwise() - mu_source;
  const Eigen::Matrix3Xd target_c = target.colwise() - mu_target;
  const Eigen::Matrix3d sigma = target_c * w.asDiagonal() * source_c.transpose();

  // R = U S V^T with S = diag(1, 1, det(U V^T)) so that R is a rotation, not a reflection.
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(sigma, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d s = Eigen::Matrix3d::Identity();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0)
    s(2, 2) = -1.0;
  const Eigen::Matrix3d rotation = svd.matrixU() * s * svd.matrixV().transpose();

  RigidTransformEstimate estimate;
  estimate.T_target_source.linear() = rotation;
  estimate.T_target_source.translation() = mu_target - rotation * mu_source;
  const Eigen::Matrix3Xd residuals =
      target - ((rotation * source).colwise() + estimate.T_target_source.translation());
  estimate.rmse_m = std::sqrt(residuals.colwise().squaredNorm().dot(w));

  // Rank of the weighted source scatter: collinear points leave the rotation about
  // their line free. Tolerance relative to the spread, with an absolute floor.
  const Eigen::Matrix3d scatter = source_c * w.asDiagonal() * source_c.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scatter, Eigen::EigenvaluesOnly);
  const double l1 = std::max(eig.eigenvalues()(2), 0.0);
  const double l2 = std::max(eig.eigenvalues()(1), 0.0);
  estimate.well_conditioned = l1 > 1e-18 && std::sqrt(l2) > 1e-6 * std::sqrt(l1);
  return estimate;
}

RigidTransformEstimate
estimateRigidTransform(const pcl::PointCloud<RasterFeaturePoint>& source,
                       const pcl::PointCloud<RasterFeaturePoint>& target,
                       const pcl::Correspondences& correspondences)
{
  const auto n = static_cast<Eigen::Index>(correspondences.size());
  Eigen::Matrix3Xd source_points(3, n), target_points(3, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const pcl::Correspondence& c = correspondences[i];
    if (c.index_query < 0 || static_cast<std::size_t>(c.index_query) >= source.size() ||
        c.index_match < 0 || static_cast<std::size_t>(c.index_match) >= target.size())
      throw std::invalid_argument("estimateRigidTransform: correspondence " +
                                  std::to_string(i) + " (" + std::to_string(c.index_query) +
                                  " -> " + std::to_string(c.index_match) +
                                  ") is out of range");
    source_points.col(i) = source[c.index_query].getVector3fMap().cast<double>();
    target_points.col(i) = target[c.index_match].getVector3fMap().cast<double>();
  }
  return estimateRigidTransform(source_points, target_points);
}

double
secondaryExtent(const Eigen::Matrix3Xd& points)
{
  if (points.cols() < 2)
    return 0.0;
  const Eigen::Vector3d mean = points.rowwise().mean();
  const Eigen::Matrix3Xd centred = points.colwise() - mean;
  const Eigen::Matrix3d scatter =
      centred * centred.transpose() / static_cast<double>(points.cols());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scatter, Eigen::EigenvaluesOnly);
  return std::sqrt(std::max(eig.eigenvalues()(1), 0.0));
}

} // namespace rast
} // namespace pcl
