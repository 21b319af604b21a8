/// \file point_to_plane_target.cpp
/// \brief PointToPlaneTarget: a scan prepared once for point-to-plane refinement (voxel
/// statistics in one pass, a plane per voxel block, the planar points indexed in a voxel
/// hash map) and its nearest-neighbour search (see doc/registration.md).

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <future>
#include <pcl/registration/point_to_plane_refinement.h>
#include <pcl/registration/voxel_hash_map.h>
#include <stdexcept>
#include <utility>

namespace pcl {
namespace rast {

namespace {

Eigen::Array3i
cellOf(const Eigen::Vector3d& p, double inverse_cell_m)
{
  return (p * inverse_cell_m).array().floor().cast<int>();
}

VoxelKey
keyOf(const Eigen::Array3i& cell)
{
  return packVoxelKey(cell.x(), cell.y(), cell.z());
}

/// Raw-point statistics of one voxel: count, sum and sum of outer products.
struct VoxelStats
{
  int count = 0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sum_outer = Eigen::Matrix3d::Zero();
  Eigen::Array3i cell;
  double time_sum = 0.0; ///< of the points' times, when they have one (prepareSource())
};

/// Below these sizes a second thread costs more than it saves.
constexpr std::size_t kMinParallelPoints = 20000;
constexpr std::size_t kMinParallelVoxels = 1000;

/// Statistics of the finite points [first, last) into \a voxels, in order of first
/// appearance, indexed by \a voxel_of_cell; with their \a times (index-aligned) when
/// given.
void
voxelStats(const PointVector& points,
           const std::vector<float>* times,
           std::size_t first,
           std::size_t last,
           double inverse_voxel_m,
           VoxelHashMap& voxel_of_cell,
           std::vector<VoxelStats>& voxels)
{
  // A scan holds about one voxel per 8 points at 0.5 m: room for them from the start,
  // so the table is not rebuilt as it fills.
  voxel_of_cell.reset((last - first) / 8);
  voxels.reserve((last - first) / 4 + 16);
  // Consecutive scan points mostly share a voxel: a repeat of the last key skips the
  // table (the sums come out the same, in the same order).
  VoxelKey last_key = ~VoxelKey(0);
  int v = -1;
  for (std::size_t i = first; i < last; ++i) {
    const Eigen::Vector3d& p = points[i];
    if (!p.allFinite())
      continue;
    const Eigen::Array3i c = cellOf(p, inverse_voxel_m);
    const VoxelKey key = keyOf(c);
    if (key != last_key) {
      const auto [found, inserted] =
          voxel_of_cell.insert(key, static_cast<int>(voxels.size()));
      if (inserted) {
        voxels.emplace_back();
        voxels.back().cell = c;
      }
      v = found;
      last_key = key;
    }
    VoxelStats& s = voxels[v];
    ++s.count;
    s.sum += p;
    s.sum_outer.noalias() += p * p.transpose();
    if (times)
      s.time_sum += (*times)[i];
  }
}

/// floor(c / 2), also for negative c.
int
floorHalf(int c)
{
  return c >= 0 ? c / 2 : -((1 - c) / 2);
}

/// The voxels grouped by blocks of 2x2x2, for the 5x5x5 neighbourhoods: one spans 27
/// blocks, a hash look-up each, where the voxels one by one took 125. A VLP-16 scan in
/// 1 m voxels needs them for 59 % of its voxels (a simulated 06 world).
class VoxelBlocks
{
public:
  explicit VoxelBlocks(const std::vector<VoxelStats>& voxels)
  {
    block_of_key_.reset(voxels.size() / 2 + 16);
    blocks_.reserve(voxels.size() / 2 + 16);
    for (std::size_t v = 0; v < voxels.size(); ++v) {
      const Eigen::Array3i& c = voxels[v].cell;
      const auto [b, inserted] = block_of_key_.insert(
          packVoxelKey(floorHalf(c.x()), floorHalf(c.y()), floorHalf(c.z())),
          static_cast<int>(blocks_.size()));
      if (inserted)
        blocks_.emplace_back();
      const int child = (c.x() & 1) | ((c.y() & 1) << 1) | ((c.z() & 1) << 2);
      blocks_[b].voxel[child] = static_cast<int>(v);
      blocks_[b].occupied |= static_cast<std::uint8_t>(1u << child);
    }
  }

  /// The voxel of each offset (dx, dy, dz) from \a cell within the 5x5x5 cube, or -1,
  /// at ((dx + 2) * 5 + dy + 2) * 5 + dz + 2: x slowest, as a look-up per offset goes.
  void cube5(const Eigen::Array3i& cell, std::array<int, 125>& voxel_at) const
  {
    voxel_at.fill(-1);
    // The children with offset 0 or 1 along each axis (child = x | y << 1 | z << 2).
    static constexpr std::uint8_t kAxisChildren[3][2] = {
        {0x55, 0xAA}, {0x33, 0xCC}, {0x0F, 0xF0}};
    // Per axis: the first of the 3 blocks, and for each the children within the cube.
    int first[3];
    std::uint8_t within[3][3];
    for (int a = 0; a < 3; ++a) {
      first[a] = floorHalf(cell[a] - 2);
      for (int i = 0; i < 3; ++i) {
        const int c0 = 2 * (first[a] + i); // the block's first cell along the axis
        within[a][i] =
            static_cast<std::uint8_t>((c0 >= cell[a] - 2 ? kAxisChildren[a][0] : 0) |
                                      (c0 + 1 <= cell[a] + 2 ? kAxisChildren[a][1] : 0));
      }
    }
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        for (int l = 0; l < 3; ++l) {
          const int b =
              block_of_key_.find(packVoxelKey(first[0] + i, first[1] + j, first[2] + l));
          if (b < 0)
            continue;
          const Block& block = blocks_[b];
          unsigned m = block.occupied & within[0][i] & within[1][j] & within[2][l];
          while (m != 0) {
            const int child = __builtin_ctz(m);
            m &= m - 1;
            const int dx = 2 * (first[0] + i) + (child & 1) - cell.x() + 2;
            const int dy = 2 * (first[1] + j) + ((child >> 1) & 1) - cell.y() + 2;
            const int dz = 2 * (first[2] + l) + (child >> 2) - cell.z() + 2;
            voxel_at[(dx * 5 + dy) * 5 + dz] = block.voxel[child];
          }
        }
  }

private:
  struct Block
  {
    std::array<int, 8> voxel; ///< by child; valid where occupied has its bit
    std::uint8_t occupied = 0;
  };
  VoxelHashMap block_of_key_;
  std::vector<Block> blocks_;
};

/// The plane of \a voxel, fitted to the raw points of its 3x3x3 voxel block (5x5x5
/// where that holds fewer than normal_neighbours, found by \a blocks): false where that
/// neighbourhood is not planar (PointToPlaneParams::max_surface_variation) or is one
/// scan ring. The voxels are summed in the order of their offsets either way.
bool
planeNormal(const VoxelStats& voxel,
            const std::vector<VoxelStats>& voxels,
            const VoxelHashMap& voxel_of_cell,
            const VoxelBlocks& blocks,
            const PointToPlaneParams& params,
            Eigen::Vector3d& normal)
{
  const int k = params.normal_neighbours;
  int count = 0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sum_outer = Eigen::Matrix3d::Zero();
  const auto add = [&](int j) {
    count += voxels[j].count;
    sum += voxels[j].sum;
    sum_outer += voxels[j].sum_outer;
  };
  for (int dx = -1; dx <= 1; ++dx)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dz = -1; dz <= 1; ++dz) {
        const int j = voxel_of_cell.find(
            packVoxelKey(voxel.cell.x() + dx, voxel.cell.y() + dy, voxel.cell.z() + dz));
        if (j >= 0)
          add(j);
      }
  if (count < k) {
    count = 0;
    sum.setZero();
    sum_outer.setZero();
    std::array<int, 125> voxel_at;
    blocks.cube5(voxel.cell, voxel_at);
    for (const int j : voxel_at)
      if (j >= 0)
        add(j);
  }
  if (count < k)
    return false;
  // E[p p^T] - mean mean^T: in double, cancellation costs ~1e-12 m^2 at 100 m range.
  const Eigen::Vector3d mean = sum / count;
  const Eigen::Matrix3d covariance = sum_outer / count - mean * mean.transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(covariance); // closed form: ~10x faster than the iterative solver
  const Eigen::Vector3d lambda = eig.eigenvalues().cwiseMax(0.0); // ascending
  const double lambda_sum = lambda.sum();
  // Collinear neighbourhoods (one scan ring) have no defined normal: lambda_1 ~ 0.
  if (lambda_sum <= 0.0 || lambda(0) > params.max_surface_variation * lambda_sum ||
      lambda(1) < 1e-2 * lambda(2))
    return false;
  normal = eig.eigenvectors().col(0).normalized();
  return true;
}

/// \a a and \a b, on two threads when \a parallel, else one after the other. An
/// exception from either reaches the caller, after both ended (a future from
/// std::async waits for its thread when destroyed).
template <typename A, typename B>
void
runBoth(bool parallel, A&& a, B&& b)
{
  if (!parallel) {
    a();
    b();
    return;
  }
  std::future<void> second = std::async(std::launch::async, std::forward<B>(b));
  a();
  second.get();
}

} // namespace

/// Voxel hash map over the planar points (KISS-ICP style): cell -> [begin, end) into a
/// cell-sorted index list; nearest neighbours are searched in the 27 cells around.
struct PointToPlaneTarget::Index
{
  double cell_m = 1.0;
  double inverse_cell_m = 1.0;
  VoxelHashMap cells;                      // cell -> slot in ranges
  std::vector<std::pair<int, int>> ranges; // [begin, end) in order
  std::vector<int> order;                  // point indices sorted by cell
  // Point coordinates in `order`, float for a compact, cache-friendly scan.
  std::vector<Eigen::Vector3f, Eigen::aligned_allocator<Eigen::Vector3f>> ordered_points;
};

PointToPlaneTarget::PointToPlaneTarget() = default;
PointToPlaneTarget::~PointToPlaneTarget() = default;
PointToPlaneTarget::PointToPlaneTarget(PointToPlaneTarget&&) noexcept = default;
PointToPlaneTarget&
PointToPlaneTarget::operator=(PointToPlaneTarget&&) noexcept = default;

void
PointToPlaneTarget::buildIndex(double cell_size_m)
{
  auto index = std::make_unique<Index>();
  index->cell_m = cell_size_m;
  index->inverse_cell_m = 1.0 / cell_size_m;
  const std::size_t n = points_.size();
  std::vector<VoxelKey> keys(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Array3i c = cellOf(points_[i], index->inverse_cell_m);
    keys[i] = keyOf(c);
  }
  index->order.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    index->order[i] = static_cast<int>(i);
  std::sort(index->order.begin(), index->order.end(), [&keys](int a, int b) {
    return keys[a] < keys[b];
  });
  index->cells.reset(n);
  index->ordered_points.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    const int i = index->order[k];
    index->ordered_points[k] = points_[i].cast<float>();
    if (k == 0 || keys[i] != keys[index->order[k - 1]]) {
      index->cells.insert(keys[i], static_cast<int>(index->ranges.size()));
      index->ranges.emplace_back(static_cast<int>(k), static_cast<int>(k));
    }
    index->ranges.back().second = static_cast<int>(k) + 1;
  }
  index_ = std::move(index);
}

void
PointToPlaneTarget::build(const PointVector& points, const PointToPlaneParams& params)
{
  build(points, params, 0, Times());
}

void
PointToPlaneTarget::build(const PointVector& points,
                          const PointToPlaneParams& params,
                          std::size_t max_planes,
                          const Times& times)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("PointToPlaneTarget::build: invalid params: " + why);
  const std::vector<float>* times_in = times.in;
  // 1. Voxel statistics of the raw points in one pass (no per-point neighbour search).
  const double voxel_m =
      params.target_voxel_size_m > 0.0 ? params.target_voxel_size_m : 0.3;
  const double inverse_voxel_m = 1.0 / voxel_m;
  // With two threads, each takes half of the points; the second half's voxels are then
  // merged into the first's in order of first appearance: the voxels come out in the
  // order one pass finds them (only the summation order of their sums differs).
  const bool parallel = params.threads >= 2 && points.size() >= kMinParallelPoints;
  const std::size_t half = parallel ? points.size() / 2 : points.size();
  VoxelHashMap voxel_of_cell, second_of_cell;
  std::vector<VoxelStats> voxels, second;
  runBoth(
      parallel,
      [&] {
        voxelStats(points, times_in, 0, half, inverse_voxel_m, voxel_of_cell, voxels);
      },
      [&] {
        voxelStats(points,
                   times_in,
                   half,
                   points.size(),
                   inverse_voxel_m,
                   second_of_cell,
                   second);
      });
  for (const VoxelStats& s2 : second) {
    const auto [v, inserted] =
        voxel_of_cell.insert(keyOf(s2.cell), static_cast<int>(voxels.size()));
    if (inserted) {
      voxels.push_back(s2);
      continue;
    }
    VoxelStats& s1 = voxels[v];
    s1.count += s2.count;
    s1.sum += s2.sum;
    s1.sum_outer += s2.sum_outer;
    s1.time_sum += s2.time_sum;
  }
  if (static_cast<int>(voxels.size()) < 3)
    throw std::invalid_argument(
        "PointToPlaneTarget::build: " + std::to_string(voxels.size()) +
        " occupied voxels, need at least 3");

  // 2. Plane of each voxel: fitted to the raw points of its 3x3x3 voxel block (a
  // neighbourhood of ~1.5 voxels radius); normal = eigenvector of the smallest
  // eigenvalue of their covariance; keep voxels whose neighbourhood is planar.
  // A source needs at most max_planes planes: fit them on evenly spread voxels only.
  const std::size_t stride =
      max_planes > 0 ? std::max<std::size_t>(1, voxels.size() / (2 * max_planes)) : 1;
  const std::size_t fitted = (voxels.size() + stride - 1) / stride;
  // Two threads take the first and the second half of the voxels fitted; their planes
  // are concatenated in order, as one thread finds them.
  const bool parallel_fit = params.threads >= 2 && fitted >= kMinParallelVoxels;
  const std::size_t split = parallel_fit ? fitted / 2 : fitted;
  PointVector planar_points, planar_normals, second_points, second_normals;
  std::vector<float> planar_times, second_times;
  const VoxelBlocks blocks(voxels);
  const auto fit = [&](std::size_t first,
                       std::size_t last,
                       PointVector& out_points,
                       PointVector& out_normals,
                       std::vector<float>& out_times) {
    out_points.reserve(last - first);
    out_normals.reserve(last - first);
    for (std::size_t j = first; j < last; ++j) {
      Eigen::Vector3d normal;
      const VoxelStats& voxel = voxels[j * stride];
      if (planeNormal(voxel, voxels, voxel_of_cell, blocks, params, normal)) {
        out_points.push_back(voxel.sum / voxel.count);
        out_normals.push_back(normal);
        if (times_in)
          out_times.push_back(static_cast<float>(voxel.time_sum / voxel.count));
      }
    }
  };
  runBoth(
      parallel_fit,
      [&] { fit(0, split, planar_points, planar_normals, planar_times); },
      [&] { fit(split, fitted, second_points, second_normals, second_times); });
  planar_points.insert(planar_points.end(), second_points.begin(), second_points.end());
  planar_normals.insert(
      planar_normals.end(), second_normals.begin(), second_normals.end());
  planar_times.insert(planar_times.end(), second_times.begin(), second_times.end());
  if (planar_points.empty())
    throw std::invalid_argument(
        "PointToPlaneTarget::build: no planar target point among " +
        std::to_string(voxels.size()) + " voxels");
  points_ = std::move(planar_points);
  normals_ = std::move(planar_normals);
  if (times.out)
    *times.out = std::move(planar_times);
  buildIndex(std::max(voxel_m, 0.5 * params.max_correspondence_distance_m));
}

void
PointToPlaneTarget::build(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                          const PointToPlaneParams& params)
{
  build(toPointVector(cloud), params);
}

void
PointToPlaneTarget::build(const pcl::PointCloud<pcl::PointNormal>& cloud_with_normals)
{
  PointVector points, normals;
  for (const auto& p : cloud_with_normals.points) {
    const Eigen::Vector3d point(p.x, p.y, p.z);
    const Eigen::Vector3d normal(p.normal_x, p.normal_y, p.normal_z);
    if (!point.allFinite() || !normal.allFinite() || normal.norm() < 1e-6)
      continue;
    points.push_back(point);
    normals.push_back(normal.normalized());
  }
  if (points.empty())
    throw std::invalid_argument("PointToPlaneTarget::build: none of the " +
                                std::to_string(cloud_with_normals.size()) +
                                " points has a finite, non-zero normal");
  points_ = std::move(points);
  normals_ = std::move(normals);
  buildIndex(0.5); // the default max_correspondence_distance_m / 2
}

bool
PointToPlaneTarget::nearest(const Eigen::Vector3d& query,
                            double max_distance_m,
                            Eigen::Vector3d& point,
                            Eigen::Vector3d& normal) const
{
  CellLookup lookup;
  return nearest(query, max_distance_m, point, normal, lookup);
}

namespace {
/// A slot of CellLookup not looked up yet.
constexpr int kUnknownSlot = -2;
} // namespace

bool
PointToPlaneTarget::nearest(const Eigen::Vector3d& query,
                            double max_distance_m,
                            Eigen::Vector3d& point,
                            Eigen::Vector3d& normal,
                            CellLookup& lookup) const
{
  if (!index_ || points_.empty())
    return false;
  const Index& index = *index_;
  const Eigen::Vector3f q = query.cast<float>();
  const Eigen::Array3f scaled = q.array() * static_cast<float>(index.inverse_cell_m);
  const Eigen::Array3f floor = scaled.floor();
  const Eigen::Array3i cell = floor.cast<int>();
  const VoxelKey cell_key = packVoxelKey(cell.x(), cell.y(), cell.z());
  if (lookup.cell != cell_key || lookup.target != &index) {
    lookup.target = &index;
    lookup.cell = cell_key;
    lookup.slots.fill(kUnknownSlot);
  }
  // Squared distances to the lower and upper faces of the query's cell, per axis.
  const float cell_m = static_cast<float>(index.cell_m);
  const Eigen::Array3f to_lower = (scaled - floor) * cell_m;
  const Eigen::Array3f to_upper = cell_m - to_lower;
  float best_sq = static_cast<float>(max_distance_m * max_distance_m);
  int best = -1;
  // Own cell first, then the 26 neighbours, skipping any farther than the best so far.
  static constexpr int kOffsets[3] = {0, -1, 1};
  int n = 0; // the neighbour's place in lookup.slots
  for (const int dx : kOffsets) {
    const float gx = dx < 0   ? to_lower.x() * to_lower.x()
                     : dx > 0 ? to_upper.x() * to_upper.x()
                              : 0.f;
    if (gx >= best_sq) {
      n += 9;
      continue;
    }
    for (const int dy : kOffsets) {
      const float gy = gx + (dy < 0   ? to_lower.y() * to_lower.y()
                             : dy > 0 ? to_upper.y() * to_upper.y()
                                      : 0.f);
      if (gy >= best_sq) {
        n += 3;
        continue;
      }
      for (const int dz : kOffsets) {
        const float gz = gy + (dz < 0   ? to_lower.z() * to_lower.z()
                               : dz > 0 ? to_upper.z() * to_upper.z()
                                        : 0.f);
        int& slot = lookup.slots[n++];
        if (gz >= best_sq)
          continue;
        if (slot == kUnknownSlot)
          slot =
              index.cells.find(packVoxelKey(cell.x() + dx, cell.y() + dy, cell.z() + dz));
        if (slot < 0)
          continue;
        const auto [begin, end] = index.ranges[slot];
        for (int k = begin; k < end; ++k) {
          const float d_sq = (index.ordered_points[k] - q).squaredNorm();
          if (d_sq < best_sq) {
            best_sq = d_sq;
            best = k;
          }
        }
      }
    }
  }
  if (best < 0)
    return false;
  point = points_[index.order[best]];
  normal = normals_[index.order[best]];
  return true;
}

} // namespace rast
} // namespace pcl
