/// \file pose_graph.cpp
/// \brief Pose-graph optimization with Ceres: build problem, solve, write back; and the
/// evaluation of a graph without optimizing (chi2, inconsistent edges). The graph as
/// plain data is in pose_graph_data.cpp.

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <ceres/ceres.h>
#include <cmath>
#include <memory>
#include <pcl/slam/pose_graph.h>
#include <sstream>
#include <stdexcept>

namespace pcl {
namespace rast {

namespace {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

/// A square root S of the information matrix Omega with S^T S = Omega, so that
/// |S r|^2 = r^T Omega r. From the eigen-decomposition, which (unlike Cholesky)
/// also accepts a semi-definite Omega; slightly negative eigenvalues are clamped.
Matrix6d
sqrtInformation(const Matrix6d& information)
{
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(information);
  const Eigen::Matrix<double, 6, 1> sqrt_values =
      eig.eigenvalues().cwiseMax(0.0).cwiseSqrt();
  return sqrt_values.asDiagonal() * eig.eigenvectors().transpose();
}

// Residual of one edge a -> b with measurement (t_ab_measured, q_ab_measured).
//
// With node poses (p_a, q_a) and (p_b, q_b) in the world frame, the estimated
// relative pose of b in a is
//
//   q_ab_estimated = q_a^-1 * q_b
//   t_ab_estimated = q_a^-1 * (p_b - p_a)
//
// and the error between measurement and estimate is
//
//   [ t_ab_estimated - t_ab_measured                         ]
//   [ 2 * vec(q_ab_measured * q_ab_estimated^-1)             ]
//
// where 2 * vec(dq) is the small-angle rotation error (rotation vector for small
// dq; the sign of dq does not change the squared norm). The residual is the error
// whitened by the square root of the information matrix: r = S * error, so that
// |r|^2 = error^T Omega error (translation first, then rotation, as g2o).
class RelativePoseError
{
public:
  RelativePoseError(const Eigen::Vector3d& t_ab_measured,
                    const Eigen::Quaterniond& q_ab_measured,
                    const Matrix6d& sqrt_information)
      : t_ab_measured_(t_ab_measured), q_ab_measured_(q_ab_measured),
        sqrt_information_(sqrt_information)
  {}

  template <typename T>
  bool operator()(const T* const p_a_ptr,
                  const T* const q_a_ptr,
                  const T* const p_b_ptr,
                  const T* const q_b_ptr,
                  T* residuals_ptr) const
  {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> p_a(p_a_ptr);
    const Eigen::Map<const Eigen::Quaternion<T>> q_a(q_a_ptr);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> p_b(p_b_ptr);
    const Eigen::Map<const Eigen::Quaternion<T>> q_b(q_b_ptr);

    const Eigen::Quaternion<T> q_a_inverse = q_a.conjugate();
    const Eigen::Quaternion<T> q_ab_estimated = q_a_inverse * q_b;
    const Eigen::Matrix<T, 3, 1> t_ab_estimated = q_a_inverse * (p_b - p_a);

    const Eigen::Quaternion<T> delta_q =
        q_ab_measured_.template cast<T>() * q_ab_estimated.conjugate();

    Eigen::Map<Eigen::Matrix<T, 6, 1>> residuals(residuals_ptr);
    residuals.template head<3>() = t_ab_estimated - t_ab_measured_.template cast<T>();
    residuals.template tail<3>() = T(2.0) * delta_q.vec();
    residuals.applyOnTheLeft(sqrt_information_.template cast<T>());
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& t_ab_measured,
                                     const Eigen::Quaterniond& q_ab_measured,
                                     const Matrix6d& sqrt_information)
  {
    return new ceres::AutoDiffCostFunction<RelativePoseError, 6, 3, 4, 3, 4>(
        new RelativePoseError(t_ab_measured, q_ab_measured, sqrt_information));
  }

  EIGEN_MAKE_ALIGNED_OPERATOR_NEW

private:
  const Eigen::Vector3d t_ab_measured_;
  const Eigen::Quaterniond q_ab_measured_;
  const Matrix6d sqrt_information_;
};

/// The Ceres loss for a choice; nullptr means plain least squares.
/// Ceres takes ownership of the returned loss when it is attached to a residual
/// block (the Problem's default loss_function_ownership).
ceres::LossFunction*
makeLoss(const RobustLoss& loss)
{
  switch (loss.type) {
  case RobustLossType::kNone:
    return nullptr;
  case RobustLossType::kHuber:
    return new ceres::HuberLoss(loss.scale);
  case RobustLossType::kCauchy:
    return new ceres::CauchyLoss(loss.scale);
  }
  return nullptr;
}

const RobustLoss&
lossFor(const PoseGraphOptions& options, PoseGraphEdgeType type)
{
  switch (type) {
  case PoseGraphEdgeType::kOdometry:
    return options.odometry_loss;
  case PoseGraphEdgeType::kLoop:
    return options.loop_loss;
  case PoseGraphEdgeType::kOther:
    break;
  }
  return options.other_loss;
}

/// rho(s) for a loss choice, as Ceres evaluates it.
double
applyLoss(const RobustLoss& loss, double s)
{
  std::unique_ptr<ceres::LossFunction> rho(makeLoss(loss));
  if (!rho)
    return s;
  double out[3];
  rho->Evaluate(s, out);
  return out[0];
}

bool
validLoss(const RobustLoss& loss, const char* name, std::string* why)
{
  if (!(loss.scale > 0.0) || !std::isfinite(loss.scale)) {
    if (why)
      *why = std::string(name) + ".scale must be finite and > 0, got " +
             std::to_string(loss.scale);
    return false;
  }
  return true;
}

/// The optimization variables of one node: position and quaternion (x y z w),
/// stored contiguously as Ceres parameter blocks.
struct NodeState
{
  double p[3];
  double q[4];
};

} // namespace

// ---------------------------------------------------------------------------
// Options and summary
// ---------------------------------------------------------------------------

bool
PoseGraphOptions::isValid(std::string* why) const
{
  auto fail = [why](const std::string& reason) {
    if (why)
      *why = reason;
    return false;
  };
  if (!validLoss(loop_loss, "loop_loss", why) ||
      !validLoss(odometry_loss, "odometry_loss", why) ||
      !validLoss(other_loss, "other_loss", why))
    return false;
  if (max_iterations < 1)
    return fail("max_iterations must be >= 1, got " + std::to_string(max_iterations));
  if (num_threads < 1)
    return fail("num_threads must be >= 1, got " + std::to_string(num_threads));
  if (!(function_tolerance > 0.0) || !(gradient_tolerance > 0.0) ||
      !(parameter_tolerance > 0.0))
    return fail(
        "function_tolerance, gradient_tolerance and parameter_tolerance must be > 0");
  return true;
}

std::string
PoseGraphSummary::BriefReport() const
{
  std::ostringstream out;
  out << "Pose graph (" << num_nodes << " nodes, " << num_fixed_nodes << " fixed, "
      << num_edges << " edges): "
      << (success ? (converged ? "CONVERGED" : "NO_CONVERGENCE") : "FAILED") << ", cost "
      << initial_cost << " -> " << final_cost << ", " << iterations << " iterations, "
      << solve_time_ms << " ms";
  if (!message.empty())
    out << " (" << message << ")";
  return out.str();
}

// ---------------------------------------------------------------------------
// Optimization: build problem, solve, write back
// ---------------------------------------------------------------------------

namespace {

/// Step 3 of optimizePoseGraph: fix the gauge. Relative-pose edges only constrain poses
/// up to one global rigid transform: the problem has a 6-dof null space that makes the
/// normal equations singular. Holding one node constant removes it: the chosen gauge
/// node (default: the smallest id in the problem) and every node flagged fixed.
void
fixGauge(const PoseGraph& graph,
         const PoseGraphOptions& options,
         std::map<int, NodeState>& states,
         ceres::Problem& problem,
         PoseGraphSummary& summary)
{
  int gauge_id = 0;
  if (options.gauge_node_id) {
    gauge_id = *options.gauge_node_id;
  } else {
    // Smallest id among the nodes in the problem (std::map iterates in id order).
    for (auto& [id, state] : states)
      if (problem.HasParameterBlock(state.q)) {
        gauge_id = id;
        break;
      }
  }
  for (auto& [id, state] : states) {
    if (!problem.HasParameterBlock(state.q))
      continue;
    if (id == gauge_id || graph.node(id).fixed) {
      problem.SetParameterBlockConstant(state.p);
      problem.SetParameterBlockConstant(state.q);
      ++summary.num_fixed_nodes;
    }
  }
  if (summary.num_fixed_nodes == 0)
    summary.message = "warning: gauge node " + std::to_string(gauge_id) +
                      " has no edge and no node is fixed: gauge left free; ";
}

/// Step 4: Levenberg-Marquardt with a sparse Cholesky (SuiteSparse when available).
ceres::Solver::Options
solverOptions(const PoseGraphOptions& options)
{
  ceres::Solver::Options solver_options;
  solver_options.minimizer_type = ceres::TRUST_REGION;
  solver_options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  solver_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  solver_options.sparse_linear_algebra_library_type =
      ceres::IsSparseLinearAlgebraLibraryTypeAvailable(ceres::SUITE_SPARSE)
          ? ceres::SUITE_SPARSE
          : ceres::EIGEN_SPARSE;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.num_threads = options.num_threads;
  solver_options.function_tolerance = options.function_tolerance;
  solver_options.gradient_tolerance = options.gradient_tolerance;
  solver_options.parameter_tolerance = options.parameter_tolerance;
  solver_options.minimizer_progress_to_stdout = options.verbose;
  solver_options.logging_type =
      options.verbose ? ceres::PER_MINIMIZER_ITERATION : ceres::SILENT;
  return solver_options;
}

} // namespace

PoseGraphSummary
optimizePoseGraph(PoseGraph& graph, const PoseGraphOptions& options)
{
  std::string why;
  if (!options.isValid(&why))
    throw std::invalid_argument("optimizePoseGraph: invalid options: " + why);
  if (options.gauge_node_id && !graph.hasNode(*options.gauge_node_id))
    throw std::invalid_argument("optimizePoseGraph: gauge_node_id " +
                                std::to_string(*options.gauge_node_id) +
                                " is not a node");

  PoseGraphSummary summary;
  summary.num_edges = static_cast<int>(graph.numEdges());
  if (graph.numEdges() == 0) {
    summary.success = true;
    summary.converged = true;
    summary.message = "no edges: nothing to optimize";
    return summary;
  }

  // 1. Copy the node poses into parameter blocks (the graph stays untouched if
  //    the solve fails).
  std::map<int, NodeState> states;
  for (const auto& [id, node] : graph.nodes()) {
    NodeState state;
    Eigen::Map<Eigen::Vector3d>(state.p) = node.p_world_node;
    Eigen::Map<Eigen::Quaterniond>(state.q) = node.q_world_node;
    states.emplace(id, state);
  }

  // 2. Build the problem: one residual block per edge. The problem owns the cost
  //    functions, losses and manifolds (Ceres' default ownership).
  ceres::Problem problem;
  for (const PoseGraphEdge& edge : graph.edges()) {
    NodeState& a = states.at(edge.from);
    NodeState& b = states.at(edge.to);
    ceres::CostFunction* cost = RelativePoseError::Create(
        edge.t_from_to, edge.q_from_to, sqrtInformation(edge.information));
    problem.AddResidualBlock(
        cost, makeLoss(lossFor(options, edge.type)), a.p, a.q, b.p, b.q);
  }
  for (auto& [id, state] : states) {
    if (!problem.HasParameterBlock(state.q))
      continue; // isolated node: not part of the problem
    problem.SetManifold(state.q, new ceres::EigenQuaternionManifold);
    ++summary.num_nodes;
  }

  // 3. Fix the gauge.
  fixGauge(graph, options, states, problem, summary);

  // 4. Solve.
  const ceres::Solver::Options solver_options = solverOptions(options);
  std::string solver_why;
  if (!solver_options.IsValid(&solver_why)) {
    summary.message += "invalid solver options: " + solver_why;
    return summary;
  }

  ceres::Solver::Summary ceres_summary;
  ceres::Solve(solver_options, &problem, &ceres_summary);

  summary.initial_cost = ceres_summary.initial_cost;
  summary.final_cost = ceres_summary.final_cost;
  summary.iterations =
      ceres_summary.num_successful_steps + ceres_summary.num_unsuccessful_steps;
  summary.solve_time_ms = 1e3 * ceres_summary.total_time_in_seconds;
  summary.converged = ceres_summary.termination_type == ceres::CONVERGENCE;
  summary.success =
      ceres_summary.IsSolutionUsable() && std::isfinite(ceres_summary.final_cost);
  summary.message += ceres_summary.message;
  if (!summary.success)
    return summary;

  // 5. Write the result back.
  for (const auto& [id, state] : states) {
    if (!problem.HasParameterBlock(state.q))
      continue;
    graph.setNodePose(id,
                      Eigen::Map<const Eigen::Vector3d>(state.p),
                      Eigen::Map<const Eigen::Quaterniond>(state.q).normalized());
  }
  return summary;
}

// ---------------------------------------------------------------------------
// Evaluation without optimizing
// ---------------------------------------------------------------------------

double
edgeChi2(const PoseGraph& graph, const PoseGraphEdge& edge)
{
  const PoseGraphNode& a = graph.node(edge.from);
  const PoseGraphNode& b = graph.node(edge.to);
  const RelativePoseError error(
      edge.t_from_to, edge.q_from_to, sqrtInformation(edge.information));
  Eigen::Matrix<double, 6, 1> residual;
  error(a.p_world_node.data(),
        a.q_world_node.coeffs().data(),
        b.p_world_node.data(),
        b.q_world_node.coeffs().data(),
        residual.data());
  return residual.squaredNorm();
}

PoseGraphCost
evaluatePoseGraph(const PoseGraph& graph, const PoseGraphOptions& options)
{
  std::string why;
  if (!options.isValid(&why))
    throw std::invalid_argument("evaluatePoseGraph: invalid options: " + why);
  PoseGraphCost cost;
  cost.edge_chi2.reserve(graph.numEdges());
  for (const PoseGraphEdge& edge : graph.edges()) {
    const double chi2 = edgeChi2(graph, edge);
    cost.edge_chi2.push_back(chi2);
    cost.total_chi2 += chi2;
    cost.total_cost += 0.5 * applyLoss(lossFor(options, edge.type), chi2);
  }
  return cost;
}

std::vector<InconsistentEdge>
findInconsistentEdges(const PoseGraph& graph,
                      double chi2_threshold,
                      std::optional<PoseGraphEdgeType> only_type)
{
  if (!(chi2_threshold >= 0.0) || !std::isfinite(chi2_threshold))
    throw std::invalid_argument(
        "findInconsistentEdges: chi2_threshold must be finite and >= 0, got " +
        std::to_string(chi2_threshold));
  std::vector<InconsistentEdge> outliers;
  const auto& edges = graph.edges();
  for (std::size_t i = 0; i < edges.size(); ++i) {
    if (only_type && edges[i].type != *only_type)
      continue;
    const double chi2 = edgeChi2(graph, edges[i]);
    if (chi2 > chi2_threshold)
      outliers.push_back({i, chi2});
  }
  std::stable_sort(outliers.begin(), outliers.end(), [](const auto& x, const auto& y) {
    return x.chi2 > y.chi2;
  });
  return outliers;
}

} // namespace rast
} // namespace pcl
