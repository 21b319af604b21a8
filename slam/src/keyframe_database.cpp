/// \file keyframe_database.cpp
/// \brief The key-frame database of loop closing: the appearance index (multi-index
/// hashing of the ORB descriptors), eligibility by key-frames and distance travelled,
/// dense-check targets, and candidate retrieval by distance and appearance.

#include "stage_util.h"

#include <pcl/slam/keyframe_database.h>

#include <algorithm>
#include <cmath>
#include <mutex>
#include <stdexcept>
#include <tuple>

namespace pcl {
namespace rast {

namespace {

constexpr double kDenseResolutionM = 0.01; // int16: +-327 m, far beyond the crop radius

/// The 16-bit substring \a table of a descriptor, as a key of the inverted index.
std::uint32_t
substringKey(const OrbDescriptor& d, int table)
{
  const auto lo = static_cast<std::uint32_t>(d[2 * table]);
  const auto hi = static_cast<std::uint32_t>(d[2 * table + 1]);
  return (static_cast<std::uint32_t>(table) << KeyFrameDatabase::kSubstringBits) | (hi << 8) | lo;
}

using slam_detail::rotationDeg;

/// The features of one bucket within \a max_distance bits of \a query, as (global
/// index, distance) in bucket order. \a descriptors holds them 32 bytes apart by global
/// index. The indexed features lie scattered over megabytes, so every visit is a cache
/// miss: the ones a few steps ahead are fetched while this one is checked (a ranking
/// 1.4-2 times faster: BM_AppearanceRetrieval, and a scan ranked against a 921-key-frame
/// simulated session), and a visit reads its descriptor's cache line only.
/// How many visits ahead the scoring fetches a descriptor, or a close feature's record.
constexpr std::size_t kPrefetchAhead = 8;

using BucketScanFn = void (*)(const std::vector<std::uint32_t>& bucket,
                              const unsigned char* descriptors,
                              const OrbDescriptor& query,
                              int max_distance,
                              std::vector<std::pair<std::uint32_t, int>>& near);

template <typename Distance>
inline void
scanBucketWith(const std::vector<std::uint32_t>& bucket,
               const unsigned char* descriptors,
               const OrbDescriptor& query,
               int max_distance,
               std::vector<std::pair<std::uint32_t, int>>& near,
               Distance distance)
{
  const std::size_t n = bucket.size();
  for (std::size_t j = 0; j < n; ++j) {
    if (j + kPrefetchAhead < n)
      __builtin_prefetch(descriptors +
                         32 * static_cast<std::size_t>(bucket[j + kPrefetchAhead]));
    const int d = distance(query, descriptors + 32 * static_cast<std::size_t>(bucket[j]));
    if (d <= max_distance)
      near.emplace_back(bucket[j], d);
  }
}

void
scanBucketPortable(const std::vector<std::uint32_t>& bucket,
                   const unsigned char* descriptors,
                   const OrbDescriptor& query,
                   int max_distance,
                   std::vector<std::pair<std::uint32_t, int>>& near)
{
  scanBucketWith(bucket,
                 descriptors,
                 query,
                 max_distance,
                 near,
                 [](const OrbDescriptor& q, const unsigned char* candidate) {
                   OrbDescriptor c;
                   __builtin_memcpy(c.data(), candidate, 32);
                   return hammingDistance(q, c);
                 });
}

#if defined(__GNUC__) && (defined(__x86_64__) || defined(__i386__))
/// The same with the POPCNT instruction, compiled for it through a function attribute
/// only (the binaries stay baseline x86-64) and called when the CPU has it.
__attribute__((target("popcnt"))) void
scanBucketPopcnt(const std::vector<std::uint32_t>& bucket,
                 const unsigned char* descriptors,
                 const OrbDescriptor& query,
                 int max_distance,
                 std::vector<std::pair<std::uint32_t, int>>& near)
{
  std::uint64_t q[4];
  __builtin_memcpy(q, query.data(), 32);
  scanBucketWith(bucket,
                 descriptors,
                 query,
                 max_distance,
                 near,
                 [&q](const OrbDescriptor&, const unsigned char* candidate) {
                   std::uint64_t w[4];
                   __builtin_memcpy(w, candidate, 32);
                   return static_cast<int>(__builtin_popcountll(q[0] ^ w[0]) +
                                           __builtin_popcountll(q[1] ^ w[1]) +
                                           __builtin_popcountll(q[2] ^ w[2]) +
                                           __builtin_popcountll(q[3] ^ w[3]));
                 });
}
#endif

BucketScanFn
selectBucketScan()
{
#if defined(__GNUC__) && (defined(__x86_64__) || defined(__i386__))
  __builtin_cpu_init();
  if (__builtin_cpu_supports("popcnt"))
    return &scanBucketPopcnt;
#endif
  return &scanBucketPortable;
}

/// Motion between consecutive key-frames: the tracking's relative pose when \a kf
/// directly follows the key-frame at \a T_world_previous, else the pose difference.
double
stepLength(const KeyFrame& kf,
           const Pose3d& T_world_kf,
           KeyFrameId previous_id,
           const Pose3d& T_world_previous)
{
  if (kf.id == previous_id + 1 && !kf.T_previous_keyframe.isApprox(Pose3d::Identity()))
    return kf.T_previous_keyframe.translation().norm();
  return (T_world_kf.translation() - T_world_previous.translation()).norm();
}

} // namespace

/// \a cloud voxelized at \a voxel_m and cropped to \a radius_m around the sensor (x-y).
PointVector
KeyFrameDatabase::croppedCloud(const pcl::PointCloud<pcl::PointXYZI>& cloud, double voxel_m, double radius_m)
{
  PointVector points = voxelDownsample(toPointVector(cloud), voxel_m);
  const double r_sq = radius_m * radius_m;
  points.erase(std::remove_if(points.begin(),
                              points.end(),
                              [r_sq](const Eigen::Vector3d& p) {
                                return p.head<2>().squaredNorm() > r_sq;
                              }),
               points.end());
  return points;
}

/// The dense check's target points of a key-frame, quantized (6 bytes a point).
std::vector<KeyFrameDatabase::DensePoint>
KeyFrameDatabase::makeDenseTarget(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                          const LoopDetectorParams& params)
{
  const PointVector points =
      croppedCloud(cloud, params.dense.target_voxel_size_m, params.dense_crop_radius_m);
  std::vector<DensePoint> out;
  out.reserve(points.size());
  for (const Eigen::Vector3d& p : points) {
    const Eigen::Vector3d q = (p / kDenseResolutionM).array().round();
    if ((q.array().abs() <= 32767.0).all())
      out.push_back({static_cast<std::int16_t>(q.x()),
                     static_cast<std::int16_t>(q.y()),
                     static_cast<std::int16_t>(q.z())});
  }
  return out;
}

PointVector
KeyFrameDatabase::decodeDense(const std::vector<DensePoint>& points)
{
  PointVector out;
  out.reserve(points.size());
  for (const DensePoint& q : points)
    out.emplace_back(q[0] * kDenseResolutionM, q[1] * kDenseResolutionM, q[2] * kDenseResolutionM);
  return out;
}

KeyFrameDatabase::KeyFrameDatabase(const LoopDetectorParams& params, BlobStore::Ptr dense_store)
  : params_(params)
  , dense_store_(dense_store ? std::move(dense_store) : std::make_shared<BlobStore>())
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("KeyFrameDatabase: invalid params: " + why);
}

void
KeyFrameDatabase::setPoseSource(PoseSource source)
{
  std::unique_lock<std::shared_mutex> lock(mutex_);
  pose_source_ = std::move(source);
}

KeyFrameDatabase::~KeyFrameDatabase() = default;

std::size_t
KeyFrameDatabase::size() const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return entries_.size();
}

std::size_t
KeyFrameDatabase::numSkipped() const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return skipped_;
}

Pose3d
KeyFrameDatabase::pose(KeyFrameId id) const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = slot_of_.find(id);
  if (it == slot_of_.end())
    throw std::invalid_argument("KeyFrameDatabase::pose: unknown key-frame id " +
                                std::to_string(id));
  return poseOf(id, entries_[it->second].T_world_keyframe, snapshot());
}

void
KeyFrameDatabase::add(const KeyFrame::ConstPtr& keyframe,
                          const Pose3d& T_world_keyframe)
{
  if (!keyframe)
    throw std::invalid_argument("KeyFrameDatabase::add: null key-frame");
  if (keyframe->features.points.size() != keyframe->features.descriptors.size())
    throw std::invalid_argument(
        "KeyFrameDatabase::add: key-frame " + std::to_string(keyframe->id) + " has " +
        std::to_string(keyframe->features.points.size()) + " feature points but " +
        std::to_string(keyframe->features.descriptors.size()) + " descriptors");
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (slot_of_.count(keyframe->id))
    throw std::invalid_argument("KeyFrameDatabase::add: key-frame id " +
                                std::to_string(keyframe->id) +
                                " is already in the database");
  Entry entry;
  entry.keyframe = keyframe;
  entry.T_world_keyframe = T_world_keyframe;
  entry.travel_m = advanceTail(*keyframe, T_world_keyframe);
  if (params_.dense_check && keyframe->cloud)
    entry.dense_target = dense_store_->putVector(makeDenseTarget(*keyframe->cloud, params_));
  index(*keyframe, static_cast<std::uint32_t>(entries_.size()));
  slot_of_.emplace(keyframe->id, entries_.size());
  entries_.push_back(std::move(entry));
}

void
KeyFrameDatabase::index(const KeyFrame& keyframe, std::uint32_t slot)
{
  if (params_.retrieval == AppearanceRetrieval::kNone)
    return;
  if (bucket_of_key_.empty())
    bucket_of_key_.assign(
        static_cast<std::size_t>(params_.num_hash_tables) << kSubstringBits, 0);
  for (std::size_t i = 0; i < keyframe.features.size(); ++i) {
    const OrbDescriptor& d = keyframe.features.descriptors[i];
    const auto g = static_cast<std::uint32_t>(features_.size());
    descriptors_.push_back({d});
    features_.push_back({keyframe.features.points[i].angle_deg, slot});
    for (int t = 0; t < params_.num_hash_tables; ++t) {
      std::uint32_t& b = bucket_of_key_[substringKey(d, t)];
      if (b == 0) {
        buckets_.emplace_back();
        b = static_cast<std::uint32_t>(buckets_.size());
      } else if (buckets_[b - 1].saturated()) {
        continue;
      }
      std::vector<std::uint32_t>& features = buckets_[b - 1].features;
      features.push_back(g);
      // A bucket past max_bucket_size is never read again (retrieval skips buckets
      // larger than the cap, and buckets only grow), so its list is dropped. In a
      // simulated town ~60 % of the postings would land in such buckets.
      if (params_.max_bucket_size > 0 &&
          features.size() > static_cast<std::size_t>(params_.max_bucket_size))
        features = std::vector<std::uint32_t>(); // saturated()
    }
  }
}

KeyFrameDatabase::MemoryUsage
KeyFrameDatabase::memoryUsage() const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  MemoryUsage m;
  for (const Entry& e : entries_)
    (dense_store_->spilled() ? m.dense_targets_on_disk : m.dense_targets) += e.dense_target.bytes;
  m.appearance_features = descriptors_.capacity() * sizeof(IndexedDescriptor) +
                          features_.capacity() * sizeof(IndexedFeature);
  m.appearance_keys = bucket_of_key_.capacity() * sizeof(std::uint32_t);
  m.appearance_index = buckets_.capacity() * sizeof(Bucket);
  for (const Bucket& bucket : buckets_)
    m.appearance_index += bucket.features.capacity() * sizeof(std::uint32_t);
  return m;
}

const KeyFrameDatabase::Bucket*
KeyFrameDatabase::bucketOf(std::uint32_t key) const
{
  const std::uint32_t b = key < bucket_of_key_.size() ? bucket_of_key_[key] : 0;
  return b > 0 ? &buckets_[b - 1] : nullptr;
}

void
KeyFrameDatabase::updatePose(KeyFrameId id, const Pose3d& T_world_keyframe)
{
  std::unique_lock<std::shared_mutex> lock(mutex_);
  const auto it = slot_of_.find(id);
  if (it == slot_of_.end())
    throw std::invalid_argument("KeyFrameDatabase::updatePose: unknown key-frame id " +
                                std::to_string(id));
  entries_[it->second].T_world_keyframe = T_world_keyframe;
}

void
KeyFrameDatabase::updatePoses(const PoseVector& T_world_by_id)
{
  std::unique_lock<std::shared_mutex> lock(mutex_);
  for (Entry& e : entries_)
    if (e.keyframe->id < T_world_by_id.size())
      e.T_world_keyframe = T_world_by_id[e.keyframe->id];
  if (tail_ && tail_->id < T_world_by_id.size())
    tail_->T_world_keyframe = T_world_by_id[tail_->id];
}

// ---------------------------------------------------------------- candidates

PoseVector
KeyFrameDatabase::snapshot() const
{
  return pose_source_ ? pose_source_() : PoseVector();
}

const Pose3d&
KeyFrameDatabase::poseOf(KeyFrameId id, const Pose3d& own, const PoseVector& snapshot) const
{
  return id < snapshot.size() ? snapshot[id] : own;
}

double
KeyFrameDatabase::travelTo(const KeyFrame& query,
                           const Pose3d& T_world_query,
                           const PoseVector& snapshot) const
{
  if (!tail_)
    return 0.0;
  return tail_->travel_m + stepLength(query,
                                      T_world_query,
                                      tail_->id,
                                      poseOf(tail_->id, tail_->T_world_keyframe, snapshot));
}

double
KeyFrameDatabase::advanceTail(const KeyFrame& keyframe, const Pose3d& T_world_keyframe)
{
  const double travel_m = travelTo(keyframe, T_world_keyframe, snapshot());
  tail_ = Tail{keyframe.id, T_world_keyframe, travel_m};
  return travel_m;
}

void
KeyFrameDatabase::skip(const KeyFrame& keyframe, const Pose3d& T_world_keyframe)
{
  std::unique_lock<std::shared_mutex> lock(mutex_);
  advanceTail(keyframe, T_world_keyframe);
  ++skipped_;
}

std::optional<KeyFrameId>
KeyFrameDatabase::covering(const KeyFrame& query,
                               const Pose3d& T_world_query,
                               double radius_m,
                               double angle_deg) const
{
  if (!(radius_m > 0.0) || !(angle_deg > 0.0))
    throw std::invalid_argument("KeyFrameDatabase::covering: radius_m (" +
                                std::to_string(radius_m) + ") and angle_deg (" +
                                std::to_string(angle_deg) + ") must be positive");
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const PoseVector poses = snapshot();
  const std::vector<char> eligible =
      eligibleSlots(query, travelTo(query, T_world_query, poses));
  std::optional<KeyFrameId> best;
  double best_distance = radius_m;
  for (std::size_t s = 0; s < entries_.size(); ++s) {
    if (!eligible[s])
      continue;
    const Pose3d& T =
        poseOf(entries_[s].keyframe->id, entries_[s].T_world_keyframe, poses);
    const double d = (T.translation() - T_world_query.translation()).norm();
    if (d > best_distance)
      continue;
    if (rotationDeg(T.inverse() * T_world_query) > angle_deg)
      continue;
    best_distance = d;
    best = entries_[s].keyframe->id;
  }
  return best;
}

std::vector<char>
KeyFrameDatabase::eligibleSlots(const KeyFrame& query, double query_travel_m) const
{
  std::vector<char> eligible(entries_.size(), 0);
  for (std::size_t s = 0; s < entries_.size(); ++s) {
    const auto gap = std::abs(static_cast<std::int64_t>(query.id) -
                              static_cast<std::int64_t>(entries_[s].keyframe->id));
    eligible[s] =
        gap >= params_.min_keyframe_gap &&
        std::abs(query_travel_m - entries_[s].travel_m) >= params_.min_travel_gap_m;
  }
  return eligible;
}

void
KeyFrameDatabase::scoreAppearance(const KeyFrame& query,
                              const std::vector<char>& eligible,
                              std::vector<double>& votes) const
{
  votes.assign(entries_.size(), 0.0);
  if (params_.retrieval == AppearanceRetrieval::kNone || features_.empty())
    return;
  const std::size_t total = features_.size();
  std::size_t max_bucket = std::max<std::size_t>(
      64,
      static_cast<std::size_t>(params_.max_bucket_fraction * static_cast<double>(total)));
  if (params_.max_bucket_size > 0)
    max_bucket = std::min<std::size_t>(max_bucket, params_.max_bucket_size);

  if (params_.retrieval == AppearanceRetrieval::kSubstringVotes) {
    // Inverted index: each shared substring votes with weight log(N / n_bucket).
    for (const auto& q : query.features.descriptors)
      for (int t = 0; t < params_.num_hash_tables; ++t) {
        const Bucket* bucket = bucketOf(substringKey(q, t));
        if (!bucket || bucket->saturated() || bucket->features.size() > max_bucket)
          continue;
        const double w = std::log(static_cast<double>(total) / bucket->features.size());
        for (const std::uint32_t g : bucket->features)
          if (eligible[features_[g].slot])
            votes[features_[g].slot] += w;
      }
    return;
  }

  // Multi-index hashing: a database descriptor within r bits of q shares at least one
  // of the m substrings exactly when r < m (pigeonhole), and most of them in practice
  // for larger r; its full distance then decides. One vote per (query feature,
  // key-frame). A vote also carries the rotation it implies (difference of the ORB
  // angles): the votes of a real revisit pile up at one relative yaw.
  const int bins =
      params_.rotation_bin_deg > 0.0
          ? std::max(1, static_cast<int>(std::lround(360.0 / params_.rotation_bin_deg)))
          : 1;
  std::vector<float> histogram(entries_.size() * bins, 0.0f);
  // One vote per (query feature, key-frame): its nearest descriptor there, the lower
  // rotation bin on a tie in distance, whatever order the tables gave. Per key-frame
  // the best (distance << 32 | bin) so far, kNone where none yet; the key-frames with
  // one, in the order found. A feature found through several tables gives the same
  // vote each time: no record of the features seen, which was another miss per visit.
  constexpr std::uint64_t kNone = ~std::uint64_t(0);
  std::vector<std::uint64_t> nearest(entries_.size(), kNone);
  std::vector<std::uint32_t> voted;
  std::vector<std::pair<std::uint32_t, int>> near;
  static const BucketScanFn scan = selectBucketScan();
  const auto* indexed = reinterpret_cast<const unsigned char*>(descriptors_.data());
  static_assert(sizeof(IndexedDescriptor) == 32, "descriptors 32 bytes apart");
  const auto& descriptors = query.features.descriptors;
  for (std::size_t i = 0; i < descriptors.size(); ++i) {
    for (int t = 0; t < params_.num_hash_tables; ++t) {
      const Bucket* bucket = bucketOf(substringKey(descriptors[i], t));
      if (!bucket || bucket->saturated() || bucket->features.size() > max_bucket)
        continue;
      near.clear();
      scan(
          bucket->features, indexed, descriptors[i], params_.retrieval_max_hamming, near);
      // A third of a bucket's features may lie within retrieval_max_hamming bits (the
      // rasters' ORB descriptors are alike): their slots are fetched ahead as well.
      for (std::size_t k = 0; k < near.size(); ++k) {
        if (k + kPrefetchAhead < near.size())
          __builtin_prefetch(&features_[near[k + kPrefetchAhead].first]);
        const IndexedFeature& feature = features_[near[k].first];
        if (!eligible[feature.slot])
          continue;
        std::uint64_t& best = nearest[feature.slot];
        const auto distance = static_cast<std::uint64_t>(near[k].second);
        if (best != kNone && distance > (best >> 32))
          continue;
        const auto bin = static_cast<std::uint64_t>(slam_detail::rotationBin(
            feature.angle_deg - query.features.points[i].angle_deg, bins));
        if (best == kNone)
          voted.push_back(feature.slot);
        best = std::min(best, distance << 32 | bin);
      }
    }
    for (const std::uint32_t slot : voted) {
      histogram[slot * bins + static_cast<std::size_t>(nearest[slot] & 0xFFFFFFFFu)] +=
          1.0f;
      nearest[slot] = kNone;
    }
    voted.clear();
  }
  for (std::size_t s = 0; s < entries_.size(); ++s) {
    const float* h = &histogram[s * bins];
    if (bins == 1) {
      votes[s] = h[0];
      continue;
    }
    votes[s] = slam_detail::bestRotationWindow(h, bins).second;
  }
}

std::vector<std::pair<KeyFrameId, int>>
KeyFrameDatabase::rankByAppearance(const KeyFrame& query, const Pose3d& T_world_query) const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<std::pair<KeyFrameId, int>> ranking;
  if (params_.retrieval == AppearanceRetrieval::kNone || entries_.empty())
    return ranking;
  const auto eligible = eligibleSlots(query, travelTo(query, T_world_query, snapshot()));
  std::vector<double> votes;
  scoreAppearance(query, eligible, votes);
  std::vector<std::pair<double, std::size_t>> order;
  for (std::size_t s = 0; s < entries_.size(); ++s)
    if (eligible[s] && votes[s] > 0.0)
      order.emplace_back(votes[s] / std::sqrt(std::max<std::size_t>(
                                        1, entries_[s].keyframe->features.size())),
                         s);
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) {
    return a.first > b.first;
  });
  for (const auto& [score, s] : order)
    ranking.emplace_back(entries_[s].keyframe->id,
                         static_cast<int>(std::lround(votes[s])));
  return ranking;
}

std::vector<RetrievedKeyFrame>
KeyFrameDatabase::retrieve(const KeyFrame& query,
                           const Pose3d& T_world_query,
                           double& query_travel_m) const
{
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<RetrievedKeyFrame> out;
  if (entries_.empty())
    return out;
  const PoseVector poses = snapshot();
  auto poseAt = [&](std::size_t s) -> const Pose3d& {
    return poseOf(entries_[s].keyframe->id, entries_[s].T_world_keyframe, poses);
  };
  query_travel_m = travelTo(query, T_world_query, poses);
  const auto eligible = eligibleSlots(query, query_travel_m);

  // 1. The paper: key-frames near the query's current estimate, nearest first.
  std::vector<std::pair<double, std::size_t>> near;
  for (std::size_t s = 0; s < entries_.size(); ++s) {
    if (!eligible[s])
      continue;
    const double d =
        (poseAt(s).translation() - T_world_query.translation()).norm();
    if (d <= params_.search_radius_m)
      near.emplace_back(d, s);
  }
  std::sort(near.begin(), near.end());
  near.resize(std::min<std::size_t>(near.size(), params_.max_distance_candidates));

  // 2. Beyond the paper: the top-k key-frames by normalised appearance score.
  std::vector<double> votes;
  scoreAppearance(query, eligible, votes);
  std::vector<std::pair<double, std::size_t>> alike;
  for (std::size_t s = 0; s < entries_.size(); ++s)
    if (eligible[s] && votes[s] >= params_.min_appearance_score)
      alike.emplace_back(votes[s] / std::sqrt(std::max<std::size_t>(
                                        1, entries_[s].keyframe->features.size())),
                         s);
  std::sort(alike.begin(), alike.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
  alike.resize(std::min<std::size_t>(alike.size(), params_.max_appearance_candidates));

  // 3. Merge; verify the most promising first: found by both, then by votes, nearest.
  std::vector<std::size_t> slots;
  for (const auto& [d, s] : near)
    slots.push_back(s);
  for (const auto& [score, s] : alike)
    if (std::find(slots.begin(), slots.end(), s) == slots.end())
      slots.push_back(s);
  for (const std::size_t s : slots) {
    RetrievedKeyFrame r;
    r.keyframe = entries_[s].keyframe;
    r.T_world_keyframe = poseAt(s);
    r.travel_m = entries_[s].travel_m;
    r.dense_target = entries_[s].dense_target;
    LoopCandidate& c = r.candidate;
    c.keyframe = entries_[s].keyframe->id;
    c.distance_m =
        (poseAt(s).translation() - T_world_query.translation()).norm();
    c.appearance_score = static_cast<int>(std::lround(votes[s]));
    const bool by_distance = std::any_of(
        near.begin(), near.end(), [s](const auto& n) { return n.second == s; });
    const bool by_appearance = std::any_of(
        alike.begin(), alike.end(), [s](const auto& a) { return a.second == s; });
    c.source = by_distance && by_appearance ? LoopCandidateSource::kBoth
               : by_distance                ? LoopCandidateSource::kDistance
                                            : LoopCandidateSource::kAppearance;
    out.push_back(std::move(r));
  }
  std::stable_sort(out.begin(),
                   out.end(),
                   [](const RetrievedKeyFrame& ra, const RetrievedKeyFrame& rb) {
                     const LoopCandidate& a = ra.candidate;
                     const LoopCandidate& b = rb.candidate;
                     const bool a_both = a.source == LoopCandidateSource::kBoth;
                     const bool b_both = b.source == LoopCandidateSource::kBoth;
                     if (a_both != b_both)
                       return a_both;
                     if (a.appearance_score != b.appearance_score)
                       return a.appearance_score > b.appearance_score;
                     return a.distance_m < b.distance_m;
                   });
  return out;
}

PointVector
KeyFrameDatabase::denseTarget(const RetrievedKeyFrame& retrieved) const
{
  return decodeDense(dense_store_->getVector<DensePoint>(retrieved.dense_target));
}

PointVector
KeyFrameDatabase::denseTarget(const KeyFrame& keyframe) const
{
  BlobStore::Handle handle;
  {
    std::shared_lock<std::shared_mutex> lock(mutex_);
    const auto it = slot_of_.find(keyframe.id);
    if (it == slot_of_.end() || entries_[it->second].keyframe.get() != &keyframe)
      return {};
    handle = entries_[it->second].dense_target;
  }
  return decodeDense(dense_store_->getVector<DensePoint>(handle));
}

} // namespace rast
} // namespace pcl
