/// \file point_to_plane_system.cpp
/// \brief Solving the point-to-plane normal equations (see point_to_plane_system.h).

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <pcl/registration/point_to_plane_system.h>

namespace pcl {
namespace rast {

bool
PointToPlaneSystem::solve(Vector6d& dx) const
{
  const Eigen::LDLT<Matrix6d> ldlt(H_);
  if (ldlt.info() != Eigen::Success)
    return false;
  dx = ldlt.solve(-g_);
  return dx.allFinite();
}

PointToPlaneSystem::Step
PointToPlaneSystem::solveDegeneracyAware(double min_ratio,
                                         const Vector6d* to_anchor,
                                         double min_support,
                                         double min_derivative) const
{
  const bool support_test = min_support > 0.0;
  if (support_test && !keep_rows_)
    throw std::logic_error(
        "PointToPlaneSystem::solveDegeneracyAware: a support test needs keepRows(true)");
  Step step;
  // With a step prior: the data's normal equations plus weight * I, pulled to its
  // target.
  const Matrix6d H = H_ + prior_weight_ * Matrix6d::Identity();
  const Vector6d g = g_ - prior_weight_ * prior_target_;
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(H);
  const double threshold = min_ratio * sum_w_;
  bool constrained[6];
  for (int k = 0; k < 6; ++k) {
    const double lambda = eig.eigenvalues()(k); // the data's plus prior_weight_
    const Vector6d v = eig.eigenvectors().col(k);
    constrained[k] = lambda - prior_weight_ > threshold;
    // Translation-dominant directions only: a rotation's rows gain |lever x n| / L
    // from every far point, so its support does not tell noise from structure.
    if (constrained[k] && support_test && v.tail<3>().squaredNorm() >= 0.5) {
      double support = 0.0;
      for (const Row& row : rows_)
        if (std::abs(row.J.dot(v)) >= min_derivative)
          support += row.w;
      step.least_support =
          step.least_support < 0.0 ? support : std::min(step.least_support, support);
      constrained[k] = support >= min_support;
    }
    if (!constrained[k]) {
      ++step.degenerate_directions;
      continue;
    }
    step.dx -= v * (v.dot(g) / lambda);
  }
  if (step.degenerate_directions > 0 && to_anchor)
    for (int k = 0; k < 6; ++k)
      if (!constrained[k]) {
        const Vector6d v = eig.eigenvectors().col(k);
        step.dx += v * v.dot(*to_anchor);
      }
  step.weakest_ratio =
      sum_w_ > 0.0 ? (eig.eigenvalues()(0) - prior_weight_) / sum_w_ : 0.0;
  step.information = sum_w_ > 0.0 ? Matrix6d(H_ / sum_w_) : Matrix6d::Zero();
  return step;
}

PointToPlaneSystem::Vector6d
PointToPlaneSystem::tangent(const Eigen::Isometry3d& from,
                            const Eigen::Isometry3d& to) const
{
  const Eigen::AngleAxisd aa(to.rotation() * from.rotation().transpose());
  Vector6d delta;
  delta.head<3>() = aa.angle() * aa.axis() * rotation_length_m_;
  delta.tail<3>() = to.translation() - from.translation();
  return delta;
}

} // namespace rast
} // namespace pcl
