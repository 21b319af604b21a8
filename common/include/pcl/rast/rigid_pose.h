#pragma once
/// \file rigid_pose.h
/// \brief Rigid poses and how they stay rigid: every pose the SLAM composes and keeps
/// is re-orthonormalized (normalizedPose, composePoses), and every pose that comes from
/// outside (a file, the API) is checked against a documented tolerance and projected
/// onto SE(3) (projectToRigid).
/// \ingroup common
///
/// Why both: a pose composed from single-precision registration results carries
/// ~1e-7 of rotation error per step, and a key-frame chain of thousands of steps adds
/// it up past 1e-6. That is harmless numerically but not a rotation any more, and a
/// strict check on it would abort a long drive. Internal poses are therefore
/// normalized where they are made and kept, never rejected; only input from outside is
/// judged, with kRotationTolerance.

#include <Eigen/Geometry>

#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief A rigid transform; by convention named after its frames, e.g. T_world_lidar.
using Pose3d = Eigen::Isometry3d;
/// \brief A sequence of poses, one per frame, with Eigen's aligned allocator.
using PoseVector = std::vector<Pose3d, Eigen::aligned_allocator<Pose3d>>;

/// \brief Tolerance on a rotation block from outside (pose files, API calls): the
/// largest entry of |R^T R - I| and |det R - 1|. Files written with 6 decimals are
/// within ~1e-6; a block further off than 1e-3 is not a rotation written with too few
/// digits but something else (a scaled or sheared matrix, a wrong column order).
constexpr double kRotationTolerance = 1e-3;

/// \brief The largest entry of |R^T R - I| together with |det R - 1|: 0 for an exact
/// rotation; a reflection (det -1) gives 2.
double
rotationError(const Eigen::Matrix3d& R);

/// \brief A rotation block within this of SO(3) (rotationError) counts as normalized.
constexpr double kNormalizedRotationError = 1e-12;

/// \brief The pose with its rotation block replaced by the nearest rotation; the
/// translation is kept. For the SLAM's own poses (near-rotations): the quaternion
/// round trip is exact to ~1e-16 and costs ~50 ns. A block already within
/// kNormalizedRotationError, and non-finite input, are returned as they are.
Pose3d
normalizedPose(const Pose3d& T);

/// \brief a * b, re-orthonormalized: how poses are composed and kept in the SLAM.
inline Pose3d
composePoses(const Pose3d& T_a_b, const Pose3d& T_b_c)
{
  return normalizedPose(T_a_b * T_b_c);
}

/// \brief The pose a fraction \a s of the way from \a T_a to \a T_b: slerp of the
/// rotation (R_a exp(s log(R_a^T R_b))), lerp of the translation; \a s outside [0, 1]
/// extrapolates with the same motion. Exact at s = 0 and s = 1.
Pose3d interpolatePose(const Pose3d& T_a, const Pose3d& T_b, double s);

/// \brief Judge a pose from outside: finite, and its rotation block within
/// \a tolerance of a rotation (rotationError). On success \a out is its projection onto
/// SE(3), with the nearest rotation in the Frobenius norm (U V^T of the SVD).
/// \return false with the reason in \a why (may be null) otherwise; \a out untouched.
bool
projectToRigid(const Pose3d& T,
               Pose3d* out,
               std::string* why = nullptr,
               double tolerance = kRotationTolerance);

/// \brief projectToRigid that throws std::invalid_argument("<where>: <why>").
Pose3d
checkedRigidPose(const Pose3d& T,
                 const std::string& where,
                 double tolerance = kRotationTolerance);

/// \brief The largest rotationError over \a poses (0 for none): for checks and reports.
double
maxRotationError(const PoseVector& poses);

} // namespace rast
} // namespace pcl
