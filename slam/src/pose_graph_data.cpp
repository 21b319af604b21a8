/// \file pose_graph_data.cpp
/// \brief PoseGraph as plain data: nodes, edges and their validation (no Ceres here;
/// the optimization is in pose_graph.cpp).

#include <pcl/slam/pose_graph.h>

#include <Eigen/Eigenvalues>

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace pcl {
namespace rast {

namespace {

using Matrix6d = Eigen::Matrix<double, 6, 6>;


std::string
formatVector(const Eigen::Ref<const Eigen::VectorXd>& v)
{
  std::ostringstream out;
  out << "(";
  for (Eigen::Index i = 0; i < v.size(); ++i)
    out << (i ? " " : "") << v[i];
  out << ")";
  return out.str();
}

std::string
typeName(PoseGraphEdgeType type)
{
  switch (type) {
  case PoseGraphEdgeType::kOdometry:
    return "odometry";
  case PoseGraphEdgeType::kLoop:
    return "loop";
  case PoseGraphEdgeType::kOther:
    return "other";
  }
  return "unknown";
}

/// Normalize a quaternion, rejecting non-finite values and norms far from 1.
Eigen::Quaterniond
checkedUnitQuaternion(const Eigen::Quaterniond& q, const std::string& where)
{
  const double norm = q.norm();
  if (!q.coeffs().allFinite() || std::abs(norm - 1.0) > 1e-3)
    throw std::invalid_argument(
        where + ": quaternion (x y z w) " + formatVector(q.coeffs()) +
        " is not finite or not of unit norm (norm " + std::to_string(norm) + ")");
  return q.normalized();
}

void
checkFinitePosition(const Eigen::Vector3d& p, const std::string& where)
{
  if (!p.allFinite())
    throw std::invalid_argument(where + ": translation " + formatVector(p) +
                                " is not finite");
}

/// Split an isometry into translation and unit quaternion. A pose handed in through the
/// API is judged as input from outside (rigid_pose.h): within kRotationTolerance of a
/// rotation it is projected onto SE(3), further off it is rejected.
void
splitPose(const Pose3d& T,
          const std::string& where,
          Eigen::Vector3d& p,
          Eigen::Quaterniond& q)
{
  const Pose3d rigid = checkedRigidPose(T, where);
  p = rigid.translation();
  q = Eigen::Quaterniond(rigid.linear()).normalized();
}

/// Check that \a information is finite, symmetric and positive semi-definite.
void
checkInformation(const Matrix6d& information, const std::string& where)
{
  if (!information.allFinite())
    throw std::invalid_argument(where + ": information matrix is not finite");
  const double scale = std::max(1.0, information.cwiseAbs().maxCoeff());
  const double asymmetry = (information - information.transpose()).cwiseAbs().maxCoeff();
  if (asymmetry > 1e-9 * scale)
    throw std::invalid_argument(
        where + ": information matrix is not symmetric (max |I - I^T| = " +
        std::to_string(asymmetry) + ")");
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(information);
  const double min_eigenvalue = eig.eigenvalues().minCoeff();
  if (min_eigenvalue < -1e-9 * scale)
    throw std::invalid_argument(
        where +
        ": information matrix is not positive semi-definite (smallest "
        "eigenvalue " +
        std::to_string(min_eigenvalue) + ")");
}

} // namespace

// ---------------------------------------------------------------------------
// Plain data
// ---------------------------------------------------------------------------

Pose3d
PoseGraphNode::pose() const
{
  Pose3d T = Pose3d::Identity();
  T.linear() = q_world_node.normalized().toRotationMatrix();
  T.translation() = p_world_node;
  return T;
}

Pose3d
PoseGraphEdge::measurement() const
{
  Pose3d T = Pose3d::Identity();
  T.linear() = q_from_to.normalized().toRotationMatrix();
  T.translation() = t_from_to;
  return T;
}

void
PoseGraph::addNode(int id, const Pose3d& T_world_node, bool fixed)
{
  Eigen::Vector3d p;
  Eigen::Quaterniond q;
  splitPose(T_world_node, "PoseGraph::addNode(" + std::to_string(id) + ")", p, q);
  addNode(id, p, q, fixed);
}

void
PoseGraph::addNode(int id,
                   const Eigen::Vector3d& p_world_node,
                   const Eigen::Quaterniond& q_world_node,
                   bool fixed)
{
  const std::string where = "PoseGraph::addNode(" + std::to_string(id) + ")";
  if (hasNode(id))
    throw std::invalid_argument(where + ": node id " + std::to_string(id) +
                                " already exists");
  checkFinitePosition(p_world_node, where);
  PoseGraphNode node;
  node.p_world_node = p_world_node;
  node.q_world_node = checkedUnitQuaternion(q_world_node, where);
  node.fixed = fixed;
  nodes_.emplace(id, node);
}

std::size_t
PoseGraph::addEdge(int from,
                   int to,
                   const Pose3d& T_from_to,
                   const Eigen::Matrix<double, 6, 6>& information,
                   PoseGraphEdgeType type)
{
  PoseGraphEdge edge;
  edge.from = from;
  edge.to = to;
  splitPose(T_from_to,
            "PoseGraph::addEdge(" + std::to_string(from) + " -> " + std::to_string(to) +
                ")",
            edge.t_from_to,
            edge.q_from_to);
  edge.information = information;
  edge.type = type;
  return addEdge(edge);
}

std::size_t
PoseGraph::addEdge(const PoseGraphEdge& edge)
{
  const std::string where = "PoseGraph::addEdge(" + std::to_string(edge.from) + " -> " +
                            std::to_string(edge.to) + ", " + typeName(edge.type) + ")";
  if (!hasNode(edge.from))
    throw std::invalid_argument(where + ": unknown node id " + std::to_string(edge.from));
  if (!hasNode(edge.to))
    throw std::invalid_argument(where + ": unknown node id " + std::to_string(edge.to));
  if (edge.from == edge.to)
    throw std::invalid_argument(where + ": an edge must join two different nodes");
  checkFinitePosition(edge.t_from_to, where);
  checkInformation(edge.information, where);
  PoseGraphEdge checked = edge;
  checked.q_from_to = checkedUnitQuaternion(edge.q_from_to, where);
  edges_.push_back(checked);
  return edges_.size() - 1;
}

void
PoseGraph::removeEdge(std::size_t index)
{
  if (index >= edges_.size())
    throw std::out_of_range("PoseGraph::removeEdge: index " + std::to_string(index) +
                            " out of range (" + std::to_string(edges_.size()) +
                            " edges)");
  edges_.erase(edges_.begin() + static_cast<std::ptrdiff_t>(index));
}

void
PoseGraph::setNodePose(int id, const Pose3d& T_world_node)
{
  Eigen::Vector3d p;
  Eigen::Quaterniond q;
  splitPose(T_world_node, "PoseGraph::setNodePose(" + std::to_string(id) + ")", p, q);
  setNodePose(id, p, q);
}

void
PoseGraph::setNodePose(int id,
                       const Eigen::Vector3d& p_world_node,
                       const Eigen::Quaterniond& q_world_node)
{
  const std::string where = "PoseGraph::setNodePose(" + std::to_string(id) + ")";
  auto it = nodes_.find(id);
  if (it == nodes_.end())
    throw std::invalid_argument(where + ": unknown node id " + std::to_string(id));
  checkFinitePosition(p_world_node, where);
  const Eigen::Quaterniond q = checkedUnitQuaternion(q_world_node, where);
  it->second.p_world_node = p_world_node;
  it->second.q_world_node = q;
}

void
PoseGraph::setNodeFixed(int id, bool fixed)
{
  auto it = nodes_.find(id);
  if (it == nodes_.end())
    throw std::invalid_argument("PoseGraph::setNodeFixed: unknown node id " +
                                std::to_string(id));
  it->second.fixed = fixed;
}

const PoseGraphNode&
PoseGraph::node(int id) const
{
  auto it = nodes_.find(id);
  if (it == nodes_.end())
    throw std::out_of_range("PoseGraph::node: unknown node id " + std::to_string(id));
  return it->second;
}

} // namespace rast
} // namespace pcl
