/// \file loop_detector.cpp
/// \brief LoopDetector: its key-frame database (keyframe_database.cpp) retrieves the
/// candidates of a query, most promising first, and detect() verifies them
/// (loop_verifier.cpp) until enough are accepted.

#include "stage_util.h"

#include <pcl/slam/loop_detector.h>

#include <cmath>
#include <stdexcept>
#include <utility>

namespace pcl {
namespace rast {

namespace {


} // namespace

// ---------------------------------------------------------------- database

LoopDetector::LoopDetector(const LoopDetectorParams& params, BlobStore::Ptr dense_store)
  : params_(params), database_(params, std::move(dense_store))
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("LoopDetector: invalid params: " + why);
}

LoopDetector::~LoopDetector() = default;

std::size_t
LoopDetector::size() const
{
  return database_.size();
}

std::size_t
LoopDetector::numSkipped() const
{
  return database_.numSkipped();
}

Pose3d
LoopDetector::pose(KeyFrameId id) const
{
  return database_.pose(id);
}

void
LoopDetector::addKeyFrame(const KeyFrame::ConstPtr& keyframe,
                          const Pose3d& T_world_keyframe)
{
  database_.add(keyframe, T_world_keyframe);
}

LoopDetector::MemoryUsage
LoopDetector::memoryUsage() const
{
  return database_.memoryUsage();
}

void
LoopDetector::setPoseSource(KeyFrameDatabase::PoseSource source)
{
  database_.setPoseSource(std::move(source));
}

void
LoopDetector::updatePose(KeyFrameId id, const Pose3d& T_world_keyframe)
{
  database_.updatePose(id, T_world_keyframe);
}

void
LoopDetector::updatePoses(const PoseVector& T_world_by_id)
{
  database_.updatePoses(T_world_by_id);
}

void
LoopDetector::skipKeyFrame(const KeyFrame& keyframe, const Pose3d& T_world_keyframe)
{
  database_.skip(keyframe, T_world_keyframe);
}

std::optional<KeyFrameId>
LoopDetector::coveringKeyFrame(const KeyFrame& query,
                               const Pose3d& T_world_query,
                               double radius_m,
                               double angle_deg) const
{
  return database_.covering(query, T_world_query, radius_m, angle_deg);
}

std::vector<std::pair<KeyFrameId, int>>
LoopDetector::rankByAppearance(const KeyFrame& query, const Pose3d& T_world_query) const
{
  return database_.rankByAppearance(query, T_world_query);
}

// ---------------------------------------------------------------- detection

LoopDetection
LoopDetector::detect(const KeyFrame& query, const Pose3d& T_world_query) const
{
  LoopDetection out;
  const pcl::StopWatch t0;
  double query_travel_m = 0.0;
  const std::vector<RetrievedKeyFrame> retrieved =
      database_.retrieve(query, T_world_query, query_travel_m);
  for (const RetrievedKeyFrame& r : retrieved)
    out.candidates.push_back(r.candidate);
  out.retrieval_ms = t0.getTime();
  const pcl::StopWatch t1;
  verifyCandidates(query, T_world_query, query_travel_m, retrieved, out);
  out.num_rejected = static_cast<int>(out.verifications.size()) - out.num_accepted;
  out.verify_ms = t1.getTime();
  return out;
}

void
LoopDetector::verifyCandidates(const KeyFrame& query,
                               const Pose3d& T_world_query,
                               double query_travel_m,
                               const std::vector<RetrievedKeyFrame>& retrieved,
                               LoopDetection& out) const
{
  // 4. Verify. Candidates found by distance only are checked against odometry, with a
  // tolerance that grows with the distance travelled since them; those that also look
  // alike, or only look alike, are not (the drift may be larger than the tolerance).
  const bool scored = params_.retrieval != AppearanceRetrieval::kNone;
  for (const RetrievedKeyFrame& r : retrieved) {
    const LoopCandidate& c = r.candidate;
    if (static_cast<int>(out.verifications.size()) >= params_.max_verifications ||
        out.num_accepted >= params_.max_accepted)
      break;
    if (scored && c.appearance_score < params_.min_appearance_score) {
      // Fewer look-alike features than a verification needs: not worth the matching.
      LoopVerification v;
      v.query = query.id;
      v.candidate = c.keyframe;
      v.reason = "appearance score " + std::to_string(c.appearance_score) + " < " +
                 std::to_string(params_.min_appearance_score) + ": not verified";
      out.verifications.push_back(v);
      continue;
    }
    GuessTolerance tolerance;
    if (c.source == LoopCandidateSource::kDistance) {
      const double travel = std::abs(query_travel_m - r.travel_m);
      tolerance.translation_m =
          params_.max_odometry_deviation_m + params_.odometry_deviation_per_m * travel;
      tolerance.rotation_deg = params_.max_odometry_deviation_deg +
                               params_.odometry_deviation_deg_per_m * travel;
    }
    const Pose3d guess = r.T_world_keyframe.inverse() * T_world_query;
    out.verifications.push_back(verifyPair(query, *r.keyframe, guess, tolerance, &r));
    out.num_accepted += out.verifications.back().accepted;
  }
}

} // namespace rast
} // namespace pcl
