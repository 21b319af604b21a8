#include <pcl/slam/bundle_adjustment.h>

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <stdexcept>

namespace pcl {
namespace rast {

namespace {

/// Reprojection error of a map point in a key-frame's raster image (paper eq. 5-7).
///
/// The map point X_w is taken into the key-frame's LiDAR frame,
///   p = R_world_kf^T (X_w - t_world_kf),
/// and compared, through the raster projection C, with the feature's own 3D point o
/// (the LiDAR point behind the keypoint's pixel):
///   orthographic:  e = [(p_x - o_x) / res, (p_y - o_y) / res, (p_z - o_z) / sigma_z]
///                  (the bird's-eye pixel is linear in x, y: u, v differences are the
///                  metric differences over the resolution; z is the pixel's value),
///   pinhole:       e = [C_u(p) - C_u(o), C_v(p) - C_v(o), (p_z - o_z) / sigma_z] with
///                  C(p) = f (p + t)_{x,y} / (p_z + t_z) + t_{u,v} (eq. 7, R = I).
/// Comparing with C(o) rather than the keypoint's pixel keeps the residual consistent
/// with the 3D point the feature was lifted to (sub-pixel, and levelling-independent).
struct RasterReprojectionError
{
  RasterReprojectionError(const Eigen::Vector3d& o_keyframe,
                          const RangeRasterParams& raster,
                          double inv_sigma_z)
    : o_(o_keyframe), raster_(raster), inv_sigma_z_(inv_sigma_z)
  {}

  template <typename T>
  bool operator()(const T* const q_world_kf_ptr,
                  const T* const t_world_kf_ptr,
                  const T* const p_world_ptr,
                  T* residual) const
  {
    Eigen::Map<const Eigen::Quaternion<T>> q_world_kf(q_world_kf_ptr);
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> t_world_kf(t_world_kf_ptr);
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> p_world(p_world_ptr);
    const Eigen::Matrix<T, 3, 1> p = q_world_kf.conjugate() * (p_world - t_world_kf);

    if (raster_.projection == RasterProjection::kOrthographic) {
      const T inv_res = T(1.0 / raster_.orthographic.resolution_m);
      residual[0] = (p.x() - T(o_.x())) * inv_res;
      residual[1] = (p.y() - T(o_.y())) * inv_res;
    }
    else {
      const auto& c = raster_.pinhole;
      const T Z = p.z() + T(c.t_z_m);
      const double Zo = o_.z() + c.t_z_m;
      const double uo = c.focal_px * (o_.x() + c.t_x_m) / Zo + c.principal_u_px;
      const double vo = c.focal_px * (o_.y() + c.t_y_m) / Zo + c.principal_v_px;
      residual[0] = T(c.focal_px) * (p.x() + T(c.t_x_m)) / Z + T(c.principal_u_px) - T(uo);
      residual[1] = T(c.focal_px) * (p.y() + T(c.t_y_m)) / Z + T(c.principal_v_px) - T(vo);
    }
    residual[2] = (p.z() - T(o_.z())) * T(inv_sigma_z_);
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& o_keyframe,
                                     const RangeRasterParams& raster,
                                     double inv_sigma_z)
  {
    return new ceres::AutoDiffCostFunction<RasterReprojectionError, 3, 4, 3, 3>(
        new RasterReprojectionError(o_keyframe, raster, inv_sigma_z));
  }

  Eigen::Vector3d o_;
  RangeRasterParams raster_;
  double inv_sigma_z_;
};

/// Relative-pose error of the Ceres pose_graph_3d example:
///   e = sqrt_info * [ R_a^T (t_b - t_a) - t_ab ; 2 vec(q_ab^-1 * q_a^-1 q_b) ].
struct RelativePoseError
{
  RelativePoseError(const Pose3d& T_a_b, const Eigen::Matrix<double, 6, 6>& sqrt_info)
    : t_ab_(T_a_b.translation()), q_ab_(T_a_b.rotation()), sqrt_info_(sqrt_info)
  {}

  template <typename T>
  bool operator()(const T* const q_a_ptr,
                  const T* const t_a_ptr,
                  const T* const q_b_ptr,
                  const T* const t_b_ptr,
                  T* residual_ptr) const
  {
    Eigen::Map<const Eigen::Quaternion<T>> q_a(q_a_ptr), q_b(q_b_ptr);
    Eigen::Map<const Eigen::Matrix<T, 3, 1>> t_a(t_a_ptr), t_b(t_b_ptr);
    const Eigen::Quaternion<T> q_a_inverse = q_a.conjugate();
    const Eigen::Quaternion<T> q_ab_estimated = q_a_inverse * q_b;
    const Eigen::Matrix<T, 3, 1> t_ab_estimated = q_a_inverse * (t_b - t_a);
    const Eigen::Quaternion<T> delta_q = q_ab_.template cast<T>() * q_ab_estimated.conjugate();
    Eigen::Map<Eigen::Matrix<T, 6, 1>> residual(residual_ptr);
    residual.template block<3, 1>(0, 0) = t_ab_estimated - t_ab_.template cast<T>();
    residual.template block<3, 1>(3, 0) = T(2.0) * delta_q.vec();
    residual.applyOnTheLeft(sqrt_info_.template cast<T>());
    return true;
  }

  static ceres::CostFunction* Create(const Pose3d& T_a_b,
                                     const Eigen::Matrix<double, 6, 6>& sqrt_info)
  {
    return new ceres::AutoDiffCostFunction<RelativePoseError, 6, 4, 3, 4, 3>(
        new RelativePoseError(T_a_b, sqrt_info));
  }

  Eigen::Vector3d t_ab_;
  Eigen::Quaterniond q_ab_;
  Eigen::Matrix<double, 6, 6> sqrt_info_;
};

struct PoseBlock
{
  Eigen::Quaterniond q;
  Eigen::Vector3d t;
};

} // namespace

bool
BundleAdjustmentParams::isValid(std::string* why) const
{
  std::string reason;
  std::string raster_why;
  if (!raster.isValid(&raster_why))
    reason = "raster: " + raster_why;
  else if (!(z_sigma_m > 0.0) || !std::isfinite(z_sigma_m))
    reason = "z_sigma_m must be > 0, got " + std::to_string(z_sigma_m);
  else if (!(huber_delta_px > 0.0) || !std::isfinite(huber_delta_px))
    reason = "huber_delta_px must be > 0, got " + std::to_string(huber_delta_px);
  else if (max_iterations < 1)
    reason = "max_iterations must be >= 1, got " + std::to_string(max_iterations);
  else if (num_threads < 1)
    reason = "num_threads must be >= 1, got " + std::to_string(num_threads);
  else if (!(function_tolerance > 0.0))
    reason = "function_tolerance must be > 0, got " + std::to_string(function_tolerance);
  if (why && !reason.empty())
    *why = reason;
  return reason.empty();
}

double
reprojectionRmsPx(const BundleAdjustmentProblem& problem, const BundleAdjustmentParams& params)
{
  double sum = 0.0;
  std::size_t n = 0;
  for (const auto& obs : problem.observations) {
    const auto pose = problem.poses.find(obs.keyframe);
    const auto point = problem.points.find(obs.point);
    if (pose == problem.poses.end() || point == problem.points.end())
      continue;
    const Eigen::Quaterniond q(pose->second.rotation());
    const Eigen::Vector3d t = pose->second.translation();
    RasterReprojectionError e(obs.p_keyframe, params.raster, 1.0 / params.z_sigma_m);
    double r[3];
    e(q.coeffs().data(), t.data(), point->second.data(), r);
    sum += r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    ++n;
  }
  return n ? std::sqrt(sum / n) : 0.0;
}

namespace {

void
checkProblem(const BundleAdjustmentProblem& problem, const BundleAdjustmentParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("bundleAdjust: invalid params: " + why);
  for (const auto& obs : problem.observations)
    if (!problem.poses.count(obs.keyframe) || !problem.points.count(obs.point))
      throw std::invalid_argument("bundleAdjust: observation of unknown key-frame " +
                                  std::to_string(obs.keyframe) + " or point " +
                                  std::to_string(obs.point));
  for (const auto& c : problem.pose_constraints)
    if (!problem.poses.count(c.a) || !problem.poses.count(c.b))
      throw std::invalid_argument("bundleAdjust: pose constraint of unknown key-frame");
}

/// Step 1: a reprojection residual (Huber) per observation, a relative-pose residual
/// per constraint, on the parameter blocks in \a pose_blocks and \a point_blocks.
void
addResiduals(const BundleAdjustmentProblem& problem,
             const BundleAdjustmentParams& params,
             std::map<KeyFrameId, PoseBlock>& pose_blocks,
             std::map<MapPointId, Eigen::Vector3d>& point_blocks,
             ceres::Problem& ceres_problem)
{
  ceres::HuberLoss* huber = new ceres::HuberLoss(params.huber_delta_px); // owned by problem
  bool huber_used = false;
  for (const auto& obs : problem.observations) {
    PoseBlock& pose = pose_blocks[obs.keyframe];
    ceres_problem.AddResidualBlock(
        RasterReprojectionError::Create(obs.p_keyframe, params.raster, 1.0 / params.z_sigma_m),
        huber,
        pose.q.coeffs().data(),
        pose.t.data(),
        point_blocks[obs.point].data());
    huber_used = true;
  }
  for (const auto& c : problem.pose_constraints) {
    PoseBlock& a = pose_blocks[c.a];
    PoseBlock& b = pose_blocks[c.b];
    ceres_problem.AddResidualBlock(RelativePoseError::Create(c.T_a_b, c.sqrt_information),
                                   nullptr,
                                   a.q.coeffs().data(),
                                   a.t.data(),
                                   b.q.coeffs().data(),
                                   b.t.data());
  }
  if (!huber_used)
    delete huber;
}

/// Step 2: gauge. The poses in `fixed` (the window's border) stay constant. Without any,
/// the whole problem could slide and rotate freely (the error only depends on relative
/// poses), so the smallest id is held constant.
void
fixGauge(const BundleAdjustmentProblem& problem,
         std::map<KeyFrameId, PoseBlock>& pose_blocks,
         ceres::Manifold& quaternion_manifold,
         ceres::Problem& ceres_problem,
         BundleAdjustmentSummary& summary)
{
  std::set<KeyFrameId> fixed = problem.fixed;
  if (fixed.empty())
    fixed.insert(pose_blocks.begin()->first);
  for (auto& [id, pose] : pose_blocks) {
    if (!ceres_problem.HasParameterBlock(pose.q.coeffs().data()))
      continue;
    ceres_problem.SetManifold(pose.q.coeffs().data(), &quaternion_manifold);
    if (fixed.count(id)) {
      ceres_problem.SetParameterBlockConstant(pose.q.coeffs().data());
      ceres_problem.SetParameterBlockConstant(pose.t.data());
      ++summary.num_fixed_poses;
    }
    else {
      ++summary.num_poses;
    }
  }
}

/// Step 3: the Schur complement eliminates the points (points first). A local window
/// has few poses: the dense reduced system (Eigen) is fast and bit-for-bit reproducible,
/// unlike a multithreaded sparse factorization.
ceres::Solver::Options
solverOptions(const BundleAdjustmentParams& params,
              int num_poses,
              std::map<KeyFrameId, PoseBlock>& pose_blocks,
              std::map<MapPointId, Eigen::Vector3d>& point_blocks,
              const ceres::Problem& ceres_problem)
{
  ceres::Solver::Options options;
  options.linear_solver_type = num_poses <= 64 ? ceres::DENSE_SCHUR : ceres::SPARSE_SCHUR;
  options.max_num_iterations = params.max_iterations;
  options.num_threads = params.num_threads;
  options.function_tolerance = params.function_tolerance;
  options.logging_type = ceres::SILENT;
  options.minimizer_progress_to_stdout = false;
  auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
  for (auto& [id, p] : point_blocks)
    if (ceres_problem.HasParameterBlock(p.data()))
      ordering->AddElementToGroup(p.data(), 0);
  for (auto& [id, pose] : pose_blocks)
    if (ceres_problem.HasParameterBlock(pose.q.coeffs().data())) {
      ordering->AddElementToGroup(pose.q.coeffs().data(), 1);
      ordering->AddElementToGroup(pose.t.data(), 1);
    }
  options.linear_solver_ordering = ordering;
  return options;
}

} // namespace

BundleAdjustmentSummary
bundleAdjust(BundleAdjustmentProblem& problem, const BundleAdjustmentParams& params)
{
  checkProblem(problem, params);
  const auto start = std::chrono::steady_clock::now();
  BundleAdjustmentSummary summary;

  // Parameter blocks live in these maps (stable addresses).
  std::map<KeyFrameId, PoseBlock> pose_blocks;
  for (const auto& [id, T] : problem.poses)
    pose_blocks[id] = PoseBlock{Eigen::Quaterniond(T.rotation()).normalized(), T.translation()};
  std::map<MapPointId, Eigen::Vector3d> point_blocks = problem.points;
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem ceres_problem(problem_options);
  ceres::EigenQuaternionManifold quaternion_manifold;

  addResiduals(problem, params, pose_blocks, point_blocks, ceres_problem);
  summary.num_residuals = ceres_problem.NumResidualBlocks();
  if (summary.num_residuals == 0) {
    summary.success = true;
    summary.message = "nothing to optimize";
    return summary;
  }
  fixGauge(problem, pose_blocks, quaternion_manifold, ceres_problem, summary);
  summary.num_points = static_cast<int>(point_blocks.size());

  const ceres::Solver::Options options =
      solverOptions(params, summary.num_poses, pose_blocks, point_blocks, ceres_problem);
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(options, &ceres_problem, &ceres_summary);
  summary.initial_cost = ceres_summary.initial_cost;
  summary.final_cost = ceres_summary.final_cost;
  summary.iterations = static_cast<int>(ceres_summary.iterations.size());
  summary.message = ceres_summary.message;
  summary.success = ceres_summary.IsSolutionUsable() && std::isfinite(ceres_summary.final_cost);

  // Write back.
  if (summary.success) {
    for (auto& [id, pose] : pose_blocks) {
      Pose3d T = Pose3d::Identity();
      T.linear() = pose.q.normalized().toRotationMatrix();
      T.translation() = pose.t;
      problem.poses[id] = T;
    }
    problem.points = point_blocks;
  }
  summary.solve_time_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

} // namespace rast
} // namespace pcl
