#pragma once
/// \file pose_graph.h
/// \brief The pose-graph back end of the loop-closure thread: key-frame poses as
/// nodes, relative-pose constraints (odometry and loops) as edges, optimized with
/// Levenberg-Marquardt (Ceres). Follows the Ceres example `slam/pose_graph_3d`.
/// \ingroup slam

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstddef>
#include <map>
#include <optional>
#include <pcl/rast/rigid_pose.h>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief A node of the pose graph: the pose T_world_node of one key-frame.
struct PoseGraphNode
{
  Eigen::Vector3d p_world_node = Eigen::Vector3d::Zero();           ///< position [m]
  Eigen::Quaterniond q_world_node = Eigen::Quaterniond::Identity(); ///< unit rotation
  bool fixed = false; ///< held constant by the optimizer

  /// \brief The node pose as an isometry, T_world_node.
  Pose3d pose() const;
};

/// \brief What produced an edge; selects the robust loss applied to it.
enum class PoseGraphEdgeType
{
  kOdometry, ///< consecutive key-frames (tracking)
  kLoop,     ///< loop closure (may be false: robust loss by default)
  kOther     ///< anything else
};

/// \brief A relative-pose constraint T_from_to between two nodes, with its 6x6
/// information matrix ordered as g2o: translation (x y z) then rotation (rx ry rz),
/// the rotation part being the small-angle error 2 * vec(dq).
struct PoseGraphEdge
{
  int from = 0;                                                  ///< id of node a
  int to = 0;                                                    ///< id of node b
  Eigen::Vector3d t_from_to = Eigen::Vector3d::Zero();           ///< measured [m]
  Eigen::Quaterniond q_from_to = Eigen::Quaterniond::Identity(); ///< measured
  Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Identity();
  PoseGraphEdgeType type = PoseGraphEdgeType::kOdometry;

  /// \brief The measurement as an isometry, T_from_to.
  Pose3d measurement() const;
};

/// \brief Plain pose-graph data with validating insertion.
///
/// Nodes are keyed by id (any int, ordered); edges keep their insertion order and are
/// addressed by index. Quaternions are normalized on insertion; a quaternion whose
/// norm is farther than 1e-3 from 1 is rejected as a likely bug.
class PoseGraph
{
public:
  /// \brief Add a node. A pose whose rotation block is within kRotationTolerance
  /// (rigid_pose.h) of a rotation is projected onto SE(3); a quaternion within 1e-3 of
  /// unit norm is normalized. \throws std::invalid_argument on a duplicate id or a
  /// pose further off or non-finite, naming the value.
  void addNode(int id, const Pose3d& T_world_node, bool fixed = false);
  void addNode(int id,
               const Eigen::Vector3d& p_world_node,
               const Eigen::Quaterniond& q_world_node,
               bool fixed = false);

  /// \brief Add an edge and return its index. \throws std::invalid_argument when a
  /// node id is unknown, from == to, the measurement is non-finite or not a rigid
  /// transform, or the information matrix is non-finite, non-symmetric or not
  /// positive semi-definite (all naming the value).
  std::size_t addEdge(int from,
                      int to,
                      const Pose3d& T_from_to,
                      const Eigen::Matrix<double, 6, 6>& information,
                      PoseGraphEdgeType type = PoseGraphEdgeType::kOdometry);
  std::size_t addEdge(const PoseGraphEdge& edge);

  /// \brief Remove the edge at \a index (later indices shift down by one), e.g. a
  /// loop found inconsistent. \throws std::out_of_range on a bad index.
  void removeEdge(std::size_t index);

  /// \brief Replace the pose of an existing node (e.g. an initial guess).
  /// \throws std::invalid_argument on an unknown id or invalid pose.
  void setNodePose(int id, const Pose3d& T_world_node);
  void setNodePose(int id,
                   const Eigen::Vector3d& p_world_node,
                   const Eigen::Quaterniond& q_world_node);

  /// \brief Mark a node as held constant (or not). \throws std::invalid_argument on an
  /// unknown id.
  void setNodeFixed(int id, bool fixed);

  bool hasNode(int id) const { return nodes_.count(id) != 0; }
  /// \throws std::out_of_range on an unknown id.
  const PoseGraphNode& node(int id) const;
  const std::map<int, PoseGraphNode>& nodes() const { return nodes_; }
  const std::vector<PoseGraphEdge>& edges() const { return edges_; }
  std::size_t numNodes() const { return nodes_.size(); }
  std::size_t numEdges() const { return edges_.size(); }

private:
  std::map<int, PoseGraphNode> nodes_;
  std::vector<PoseGraphEdge> edges_;
};

/// \brief Robust loss applied to the squared, information-weighted residual of an edge.
enum class RobustLossType
{
  kNone,  ///< plain least squares
  kHuber, ///< quadratic up to `scale` sigma, linear beyond
  kCauchy ///< rho(s) = scale^2 log(1 + s / scale^2); strongly down-weights outliers
};

/// \brief A robust loss choice: type and scale in sigma units of the whitened residual.
struct RobustLoss
{
  RobustLossType type = RobustLossType::kNone;
  double scale = 1.0; ///< [sigma], > 0
};

/// \brief Settings of optimizePoseGraph.
struct PoseGraphOptions
{
  /// Loss on loop edges: loops may be false, so Cauchy by default.
  RobustLoss loop_loss{RobustLossType::kCauchy, 3.0};
  /// Loss on odometry edges: trusted, plain least squares by default.
  RobustLoss odometry_loss{RobustLossType::kNone, 1.0};
  /// Loss on edges of type kOther.
  RobustLoss other_loss{RobustLossType::kNone, 1.0};
  /// Node held constant to fix the gauge (global pose freedom); unset: the node
  /// with the smallest id. Nodes flagged `fixed` are held constant as well.
  std::optional<int> gauge_node_id;
  int max_iterations = 100;          ///< Levenberg-Marquardt iterations, >= 1
  int num_threads = 1;               ///< Ceres threads; 1 keeps results deterministic
  double function_tolerance = 1e-6;  ///< relative cost change to stop, > 0
  double gradient_tolerance = 1e-10; ///< max-norm gradient to stop, > 0
  double parameter_tolerance = 1e-8; ///< relative step size to stop, > 0
  bool verbose = false;              ///< print Ceres per-iteration progress to stdout

  /// \brief True when every field is in range; otherwise false and the reason in \a why.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Outcome of optimizePoseGraph. Costs follow the Ceres convention:
/// 0.5 * sum over edges of rho(r^T Omega r).
struct PoseGraphSummary
{
  bool success = false;   ///< a usable solution was written back into the graph
  bool converged = false; ///< a tolerance was reached (not the iteration limit)
  double initial_cost = 0.0;
  double final_cost = 0.0;
  int iterations = 0; ///< Levenberg-Marquardt steps taken (successful + unsuccessful)
  double solve_time_ms = 0.0;
  int num_nodes = 0;       ///< nodes in the problem (those touched by an edge)
  int num_fixed_nodes = 0; ///< of which held constant (gauge included)
  int num_edges = 0;
  std::string message; ///< why the solver stopped, or what went wrong

  /// \brief One line: success, costs, iterations, time, message.
  std::string BriefReport() const;
};

/// \brief Optimize the node poses of \a graph in place with Levenberg-Marquardt and a
/// sparse Cholesky solver (SuiteSparse when available, else Eigen).
///
/// Residual of an edge a -> b (the Ceres `pose_graph_3d` one), see pose_graph.cpp.
/// The graph is only changed when `success` is true. Nodes not touched by any edge
/// are left alone. With nothing to optimize (no edges) returns success.
/// \throws std::invalid_argument when \a options is invalid or the gauge node is unknown.
PoseGraphSummary optimizePoseGraph(PoseGraph& graph,
                                   const PoseGraphOptions& options = PoseGraphOptions());

/// \brief The whitened squared residual r^T Omega r of one edge at the current poses
/// (a chi-square value with 6 degrees of freedom for a correct edge and noise model).
double edgeChi2(const PoseGraph& graph, const PoseGraphEdge& edge);

/// \brief Per-edge chi2 (in edge order) and the total cost, without optimizing.
struct PoseGraphCost
{
  double total_cost = 0.0; ///< 0.5 * sum rho(chi2), with the losses of the options
  double total_chi2 = 0.0; ///< sum chi2, no loss
  std::vector<double> edge_chi2;
};

/// \brief Evaluate the cost of \a graph at its current poses (same cost as
/// optimizePoseGraph's initial_cost for the same options).
/// \throws std::invalid_argument when \a options is invalid.
PoseGraphCost evaluatePoseGraph(const PoseGraph& graph,
                                const PoseGraphOptions& options = PoseGraphOptions());

/// \brief An edge whose residual is an outlier.
struct InconsistentEdge
{
  std::size_t edge_index = 0;
  double chi2 = 0.0;
};

/// \brief Edges whose chi2 exceeds \a chi2_threshold at the current poses, worst first.
/// Call after optimizing with a robust loss on loops: a false loop is down-weighted
/// and keeps a large residual, so the loop closer can remove it and re-optimize.
/// Useful thresholds for 6 degrees of freedom: 16.8 (99 %), 22.5 (99.9 %).
/// \param[in] only_type when set, only edges of this type are reported.
/// \throws std::invalid_argument when \a chi2_threshold is negative or not finite.
std::vector<InconsistentEdge>
findInconsistentEdges(const PoseGraph& graph,
                      double chi2_threshold,
                      std::optional<PoseGraphEdgeType> only_type = std::nullopt);

} // namespace rast
} // namespace pcl
