#pragma once
/// \file point_to_plane_system.h
/// \brief The estimator part of the dense-registration core: robust weights and the 6x6
/// normal equations of point-to-plane (and plane-to-plane) residuals, solved plainly or
/// degeneracy-aware. Shared by refinePointToPlane (scan to scan, loop verification) and
/// the odometry's registration to its local map. See doc/registration.md.
/// \ingroup registration

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Robust kernels for the point-to-plane residual r, with scale s.
enum class RobustKernel
{
  kNone,        ///< least squares, w = 1
  kHuber,       ///< w = 1 for |r| <= k, k / |r| beyond; k = 1.345 s
  kTukey,       ///< w = (1 - (r/c)^2)^2 for |r| < c, 0 beyond; c = 4.685 s
  kGemanMcClure ///< w = (s^2 / (s^2 + r^2))^2
};

/// \brief The weight w(r) of residual \a r under \a kernel with scale \a s (IRLS).
inline double
robustWeight(RobustKernel kernel, double r, double s)
{
  const double a = std::abs(r);
  switch (kernel) {
  case RobustKernel::kNone:
    return 1.0;
  case RobustKernel::kHuber: { // usual tuning constant k = 1.345 sigma
    const double k = 1.345 * s;
    return a <= k ? 1.0 : k / a;
  }
  case RobustKernel::kTukey: { // usual tuning constant c = 4.685 sigma
    const double c = 4.685 * s;
    if (a >= c)
      return 0.0;
    const double u = 1.0 - (r / c) * (r / c);
    return u * u;
  }
  case RobustKernel::kGemanMcClure: {
    const double u = s * s / (s * s + r * r);
    return u * u;
  }
  }
  return 1.0;
}

/// \brief Weighted Gauss-Newton normal equations H dx = -g of a rigid motion, in the
/// tangent dx = [omega * L, dt] of a left perturbation about a pivot p0:
/// q <- Exp(omega) (q - p0) + p0 + dt. The lever of a point is q - p0 (the point itself
/// for a pivot at the origin). The rotation length L [m] scales the rotation rows to
/// metres, so that the eigenvalues of H compare across rotation and translation (a
/// rotation of 1/L rad moves a point at L metres by 1 m); L = 1 is plain radians.
class PointToPlaneSystem
{
public:
  using Vector6d = Eigen::Matrix<double, 6, 1>;
  using Matrix6d = Eigen::Matrix<double, 6, 6>;

  /// \throws std::invalid_argument when rotation_length_m is not finite and positive
  explicit PointToPlaneSystem(double rotation_length_m = 1.0)
      : rotation_length_m_(rotation_length_m)
  {
    if (!(rotation_length_m > 0.0) || !std::isfinite(rotation_length_m))
      throw std::invalid_argument(
          "PointToPlaneSystem: rotation_length_m must be finite and > 0, got " +
          std::to_string(rotation_length_m));
  }

  /// \brief Point-to-plane residual r = n . (q - c) of a point at \a lever from the
  /// pivot, weight \a w: dr/domega = lever x n, dr/ddt = n.
  void addPointToPlane(const Eigen::Vector3d& lever,
                       const Eigen::Vector3d& normal,
                       double residual,
                       double w)
  {
    Vector6d J;
    J.head<3>() = lever.cross(normal) / rotation_length_m_;
    J.tail<3>() = normal;
    H_.noalias() += w * J * J.transpose();
    g_.noalias() += w * residual * J;
    sum_w_ += w;
    if (keep_rows_)
      rows_.push_back({J, w});
  }

  /// \brief Keep the point-to-plane rows (J, w) added from now on, for the support
  /// test of solveDegeneracyAware. Plane-to-plane rows are not kept.
  void keepRows(bool keep) { keep_rows_ = keep; }

  /// \brief Plane-to-plane (GICP) residual e = q - c with 3x3 \a information, weight \a
  /// w: de/d[omega, dt] = [-[lever]x, I].
  void addPlaneToPlane(const Eigen::Vector3d& lever,
                       const Eigen::Matrix3d& information,
                       const Eigen::Vector3d& e,
                       double w)
  {
    const Eigen::Vector3d a = lever / rotation_length_m_;
    Eigen::Matrix<double, 3, 6> J;
    J.leftCols<3>() << 0.0, a.z(), -a.y(), -a.z(), 0.0, a.x(), a.y(), -a.x(), 0.0;
    J.rightCols<3>().setIdentity();
    const Eigen::Matrix<double, 6, 3> Jt_information = J.transpose() * information;
    H_.noalias() += w * Jt_information * J;
    g_.noalias() += w * Jt_information * e;
    sum_w_ += w;
  }

  /// \brief The step dx solving H dx = -g (LDLT). False when H is singular or the step
  /// is not finite (degenerate geometry).
  bool solve(Vector6d& dx) const;

  /// \brief Outcome of solveDegeneracyAware.
  struct Step
  {
    Vector6d dx = Vector6d::Zero();
    int degenerate_directions = 0; ///< eigen-directions not updated
    /// The smallest eigenvalue of H over the total weight.
    double weakest_ratio = 0.0;
    /// With a support test: the least support of a direction that passed the
    /// eigenvalue test (see solveDegeneracyAware); -1 without one.
    double least_support = -1.0;
    /// H per unit weight, H / sum(w): delta^T information delta is the mean squared
    /// residual a displacement delta adds.
    Matrix6d information = Matrix6d::Zero();
  };

  /// \brief Solve H dx = -g in H's eigenbasis, leaving dx at zero along directions whose
  /// eigenvalue is at most \a min_ratio of the total weight (Zhang et al., ICRA 2016), so
  /// that an unconstrained direction keeps its start instead of following noise. With
  /// \a to_anchor (the displacement to an anchor pose, in this tangent), the step moves
  /// to the anchor along those directions instead.
  ///
  /// With \a min_support > 0 (rows kept, keepRows), a translation-dominant direction v
  /// (|v_t|^2 >= 1/2) that passes the eigenvalue test must also be supported: the
  /// weight of the rows whose residual changes by at least \a min_derivative per unit
  /// step along v (|J . v|, in metres per metre of the tangent) must reach \a
  /// min_support. Otherwise it is degenerate as well. Many rows that each change little
  /// along v (a tunnel's walls, whose normals fitted to noisy points lean a few degrees
  /// along the road) add up to a fair eigenvalue but do not fix the motion; a few
  /// surfaces that face along v (a post, a cabinet's side) do. This is the localizability
  /// idea of X-ICP (Tuna et al., 2023), reduced to a count. \throws std::logic_error for
  /// a support test without kept rows.
  Step solveDegeneracyAware(double min_ratio,
                            const Vector6d* to_anchor = nullptr,
                            double min_support = 0.0,
                            double min_derivative = 0.3) const;

  /// \brief The displacement from \a from to \a to in this tangent: omega * L
  /// (R_to = Exp(omega) R_from), then t_to - t_from.
  Vector6d tangent(const Eigen::Isometry3d& from, const Eigen::Isometry3d& to) const;

  /// \brief A Gaussian prior on the step of solveDegeneracyAware: adds
  /// \a weight * |dx - \a to_target|^2 to the cost it solves (the rows' weights and
  /// the tangent's units). H(), g() and Step::information stay the data's. 0: none.
  void setStepPrior(const Vector6d& to_target, double weight)
  {
    prior_target_ = to_target;
    prior_weight_ = weight;
  }

  const Matrix6d& H() const { return H_; }
  const Vector6d& g() const { return g_; }
  double sumWeights() const { return sum_w_; }

private:
  double rotation_length_m_;
  Matrix6d H_ = Matrix6d::Zero();
  Vector6d g_ = Vector6d::Zero();
  double sum_w_ = 0.0;
  Vector6d prior_target_ = Vector6d::Zero();
  double prior_weight_ = 0.0;
  struct Row
  {
    Vector6d J;
    double w;
  };
  bool keep_rows_ = false;
  std::vector<Row> rows_;
};

} // namespace rast
} // namespace pcl
