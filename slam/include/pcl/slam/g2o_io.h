#pragma once
/// \file g2o_io.h
/// \brief Reading and writing 3D pose graphs in the g2o text format.
/// \ingroup slam
///
/// Supported lines (one per line, blank lines and `#` comments are skipped):
///   VERTEX_SE3:QUAT id x y z qx qy qz qw
///   EDGE_SE3:QUAT from to x y z qx qy qz qw  I11 I12 .. I16 I22 .. I26 .. I66
///   FIX id [id ...]
/// The 21 numbers after the measurement are the upper triangle of the 6x6
/// information matrix, row by row, ordered translation then rotation.

#include <pcl/slam/pose_graph.h>
#include <string>

namespace pcl {
namespace rast {

/// \brief Read a g2o pose graph. g2o has no edge types: an edge between consecutive
/// ids (|to - from| == 1) becomes kOdometry, any other edge kLoop. Vertices named by
/// `FIX` are marked fixed. Edges may precede the vertices they reference.
/// \throws std::runtime_error naming the file and the 1-based line of a malformed
/// line (unknown tag, wrong number of fields, non-numeric or non-finite value,
/// non-unit quaternion, duplicate vertex, unknown vertex, invalid information),
/// or naming the file when it cannot be opened.
PoseGraph readG2o(const std::string& path);

/// \brief Write \a graph in g2o format (full double precision, so reading it back
/// gives the same numbers), vertices in id order, edges in graph order, then one
/// `FIX` line for the fixed vertices. Edge types are not stored (see readG2o).
/// Atomic: written to a temporary file then renamed.
/// \throws std::runtime_error naming the file when it cannot be written.
void writeG2o(const std::string& path, const PoseGraph& graph);

} // namespace rast
} // namespace pcl
