/// \file rigid_pose.cpp
/// \brief Keeping poses rigid: normalization of internal poses, checks of external ones.

#include <pcl/rast/rigid_pose.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace pcl {
namespace rast {

double
rotationError(const Eigen::Matrix3d& R)
{
  const double orthogonality =
      (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  return std::max(orthogonality, std::abs(R.determinant() - 1.0));
}

Pose3d
normalizedPose(const Pose3d& T)
{
  // Already a rotation to 1e-12: left bit for bit as it is (an exact quarter turn keeps
  // its exact zeros), so normalizing is idempotent and a chain stays within ~1e-12.
  if (!T.matrix().allFinite() || rotationError(T.linear()) <= kNormalizedRotationError)
    return T;
  Pose3d out = T;
  out.linear() = Eigen::Quaterniond(T.linear()).normalized().toRotationMatrix();
  out.makeAffine();
  return out;
}

bool
projectToRigid(const Pose3d& T, Pose3d* out, std::string* why, double tolerance)
{
  auto fail = [&](const std::string& reason) {
    if (why)
      *why = reason;
    return false;
  };
  if (!T.matrix().allFinite())
    return fail("pose matrix is not finite");
  const Eigen::Matrix3d R = T.linear();
  const double error = rotationError(R);
  if (!(error <= tolerance)) {
    std::ostringstream msg;
    msg << "rotation block is not a rotation (max of |R^T R - I| and |det R - 1| is "
        << error << ", det " << R.determinant() << ", tolerance " << tolerance << ")";
    return fail(msg.str());
  }
  // Nearest rotation in the Frobenius norm: U V^T (det > 0 here, as error < 1).
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Pose3d projected = Pose3d::Identity();
  projected.linear() = svd.matrixU() * svd.matrixV().transpose();
  projected.translation() = T.translation();
  *out = projected;
  return true;
}

Pose3d
checkedRigidPose(const Pose3d& T, const std::string& where, double tolerance)
{
  Pose3d out;
  std::string why;
  if (!projectToRigid(T, &out, &why, tolerance))
    throw std::invalid_argument(where + ": " + why);
  return out;
}

double
maxRotationError(const PoseVector& poses)
{
  double worst = 0.0;
  for (const Pose3d& T : poses)
    worst = std::max(worst, rotationError(T.linear()));
  return worst;
}

Pose3d
interpolatePose(const Pose3d& T_a, const Pose3d& T_b, double s)
{
  if (s == 0.0)
    return T_a;
  if (s == 1.0)
    return T_b;
  const Eigen::AngleAxisd R_ab(Eigen::Matrix3d(T_a.linear().transpose() * T_b.linear()));
  Pose3d T = Pose3d::Identity();
  T.linear() =
      T_a.linear() * Eigen::AngleAxisd(s * R_ab.angle(), R_ab.axis()).toRotationMatrix();
  T.translation() = T_a.translation() + s * (T_b.translation() - T_a.translation());
  return T;
}

} // namespace rast
} // namespace pcl
