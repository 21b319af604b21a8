/// \file g2o_io.cpp
/// \brief g2o VERTEX_SE3:QUAT / EDGE_SE3:QUAT reader and writer.

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <pcl/rast/text_lines.h>
#include <pcl/slam/g2o_io.h>
#include <pcl/rast/atomic_file.h>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace pcl {
namespace rast {

namespace {

/// A parse error at one line of one file.
class LineError : public std::runtime_error
{
public:
  LineError(const std::string& path, std::size_t line, const std::string& what)
      : std::runtime_error("readG2o: " + path + ":" + std::to_string(line) + ": " + what)
  {}
};

double
parseDouble(const std::string& token, const std::string& path, std::size_t line)
{
  errno = 0;
  char* end = nullptr;
  const double value = std::strtod(token.c_str(), &end);
  if (token.empty() || end != token.c_str() + token.size() || errno == ERANGE)
    throw LineError(path, line, "'" + token + "' is not a number");
  if (!std::isfinite(value))
    throw LineError(path, line, "'" + token + "' is not finite");
  return value;
}

int
parseId(const std::string& token, const std::string& path, std::size_t line)
{
  errno = 0;
  char* end = nullptr;
  const long value = std::strtol(token.c_str(), &end, 10);
  if (token.empty() || end != token.c_str() + token.size() || errno == ERANGE ||
      value < std::numeric_limits<int>::min() || value > std::numeric_limits<int>::max())
    throw LineError(path, line, "'" + token + "' is not an integer id");
  return static_cast<int>(value);
}

/// Parse `x y z qx qy qz qw` starting at tokens[first].
void
parsePose(const std::vector<std::string>& tokens,
          std::size_t first,
          const std::string& path,
          std::size_t line,
          Eigen::Vector3d& t,
          Eigen::Quaterniond& q)
{
  for (int i = 0; i < 3; ++i)
    t[i] = parseDouble(tokens[first + i], path, line);
  // Eigen's coeffs() order is (x y z w), as in g2o.
  for (int i = 0; i < 4; ++i)
    q.coeffs()[i] = parseDouble(tokens[first + 3 + i], path, line);
}

struct PendingEdge
{
  std::size_t line;
  PoseGraphEdge edge;
};

} // namespace

PoseGraph
readG2o(const std::string& path)
{
  std::ifstream in(path);
  if (!in)
    throw std::runtime_error("readG2o: cannot open '" + path + "'");

  PoseGraph graph;
  std::vector<PendingEdge> edges;
  std::vector<std::pair<std::size_t, int>> fixed_ids;
  std::string text;
  std::size_t line = 0;
  while (readBoundedLine(in, text, path, line + 1)) {
    ++line;
    std::istringstream fields(text);
    std::vector<std::string> tokens;
    for (std::string token; fields >> token;)
      tokens.push_back(token);
    if (tokens.empty() || tokens[0][0] == '#')
      continue;
    const std::string& tag = tokens[0];
    const auto expect = [&](std::size_t count) {
      if (tokens.size() != count)
        throw LineError(path,
                        line,
                        tag + " needs " + std::to_string(count - 1) + " values, got " +
                            std::to_string(tokens.size() - 1));
    };

    if (tag == "VERTEX_SE3:QUAT") {
      expect(9);
      const int id = parseId(tokens[1], path, line);
      Eigen::Vector3d p;
      Eigen::Quaterniond q;
      parsePose(tokens, 2, path, line, p, q);
      try {
        graph.addNode(id, p, q);
      } catch (const std::invalid_argument& e) {
        throw LineError(path, line, e.what());
      }
    } else if (tag == "EDGE_SE3:QUAT") {
      expect(31);
      PendingEdge pending{line, PoseGraphEdge()};
      PoseGraphEdge& edge = pending.edge;
      edge.from = parseId(tokens[1], path, line);
      edge.to = parseId(tokens[2], path, line);
      parsePose(tokens, 3, path, line, edge.t_from_to, edge.q_from_to);
      std::size_t k = 10;
      for (int r = 0; r < 6; ++r)
        for (int c = r; c < 6; ++c) {
          edge.information(r, c) = parseDouble(tokens[k++], path, line);
          edge.information(c, r) = edge.information(r, c);
        }
      const long gap = static_cast<long>(edge.to) - static_cast<long>(edge.from);
      edge.type = (gap == 1 || gap == -1) ? PoseGraphEdgeType::kOdometry
                                          : PoseGraphEdgeType::kLoop;
      edges.push_back(pending);
    } else if (tag == "FIX") {
      if (tokens.size() < 2)
        throw LineError(path, line, "FIX needs at least one vertex id");
      for (std::size_t i = 1; i < tokens.size(); ++i)
        fixed_ids.emplace_back(line, parseId(tokens[i], path, line));
    } else {
      throw LineError(path,
                      line,
                      "unsupported tag '" + tag +
                          "' (expected VERTEX_SE3:QUAT, EDGE_SE3:QUAT or FIX)");
    }
  }
  if (in.bad())
    throw std::runtime_error("readG2o: error while reading '" + path + "'");

  // Edges and FIX after all vertices, so that the file order does not matter.
  for (const PendingEdge& pending : edges) {
    try {
      graph.addEdge(pending.edge);
    } catch (const std::invalid_argument& e) {
      throw LineError(path, pending.line, e.what());
    }
  }
  for (const auto& [fix_line, id] : fixed_ids) {
    if (!graph.hasNode(id))
      throw LineError(path, fix_line, "FIX names unknown vertex " + std::to_string(id));
    graph.setNodeFixed(id, true);
  }
  return graph;
}

void
writeG2o(const std::string& path, const PoseGraph& graph)
{
  std::ostringstream out;
  out.precision(std::numeric_limits<double>::max_digits10);
  const auto writePose = [&out](const Eigen::Vector3d& t, const Eigen::Quaterniond& q) {
    out << t.x() << ' ' << t.y() << ' ' << t.z() << ' ' << q.x() << ' ' << q.y() << ' '
        << q.z() << ' ' << q.w();
  };

  std::vector<int> fixed_ids;
  for (const auto& [id, node] : graph.nodes()) {
    out << "VERTEX_SE3:QUAT " << id << ' ';
    writePose(node.p_world_node, node.q_world_node);
    out << '\n';
    if (node.fixed)
      fixed_ids.push_back(id);
  }
  for (const PoseGraphEdge& edge : graph.edges()) {
    out << "EDGE_SE3:QUAT " << edge.from << ' ' << edge.to << ' ';
    writePose(edge.t_from_to, edge.q_from_to);
    for (int r = 0; r < 6; ++r)
      for (int c = r; c < 6; ++c)
        out << ' ' << edge.information(r, c);
    out << '\n';
  }
  if (!fixed_ids.empty()) {
    out << "FIX";
    for (int id : fixed_ids)
      out << ' ' << id;
    out << '\n';
  }
  try {
    writeFileAtomically(path, out.str());
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(std::string("writeG2o: ") + e.what());
  }
}

} // namespace rast
} // namespace pcl
