/// \file test_hamming_correspondence_estimation.cpp
/// \brief Hamming matching on constructed descriptors: exact matches, max distance,
/// Lowe's ratio test, mutual check, spatial gate, validation.

#include <pcl/registration/hamming_correspondence_estimation.h>

#include <gtest/gtest.h>

#include <random>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_hamming_correspondence_estimation {

namespace {

using pcl::rast::HammingMatchParams;
using pcl::rast::OrbDescriptor;
using pcl::rast::RasterFeatureSet;

/// A descriptor with the first `ones` bits set.
OrbDescriptor
withBits(int ones)
{
  OrbDescriptor d{};
  for (int b = 0; b < ones; ++b)
    d[b / 8] |= static_cast<std::uint8_t>(1u << (b % 8));
  return d;
}

/// d with bits [first, first + count) flipped.
OrbDescriptor
flipped(OrbDescriptor d, int first, int count)
{
  for (int b = first; b < first + count; ++b)
    d[b / 8] ^= static_cast<std::uint8_t>(1u << (b % 8));
  return d;
}

void
add(RasterFeatureSet& set, const OrbDescriptor& d, float x = 0.f, float y = 0.f)
{
  pcl::rast::RasterFeaturePoint p{};
  p.x = x;
  p.y = y;
  p.z = 0.f;
  set.points.push_back(p);
  set.descriptors.push_back(d);
}

OrbDescriptor
randomDescriptor(std::mt19937& rng)
{
  OrbDescriptor d;
  for (auto& byte : d)
    byte = static_cast<std::uint8_t>(rng() & 0xFF);
  return d;
}

TEST(HammingCorrespondenceEstimation, MatchesNoisyCopiesOfRandomDescriptors)
{
  std::mt19937 rng(7);
  RasterFeatureSet source, target;
  for (int i = 0; i < 200; ++i)
    add(target, randomDescriptor(rng));
  // source i is target (199 - i) with 10 bits flipped.
  for (int i = 0; i < 200; ++i)
    add(source, flipped(target.descriptors[199 - i], (i * 13) % 240, 10));

  const pcl::Correspondences c = pcl::rast::matchHamming(source, target);
  ASSERT_EQ(c.size(), 200u);
  for (const auto& m : c) {
    EXPECT_EQ(m.index_match, 199 - m.index_query);
    EXPECT_FLOAT_EQ(m.distance, 10.f);
  }
}

/// The nearest-neighbour set that comes with a ratio-tested match is what matching with
/// the ratio test and the mutual check off returns, and a superset of the strict one.
TEST(HammingCorrespondenceEstimation, NearestSetEqualsMatchingWithoutRatioOrMutualCheck)
{
  std::mt19937 rng(11);
  RasterFeatureSet source, target;
  for (int i = 0; i < 100; ++i)
    add(target, randomDescriptor(rng), static_cast<float>(i), 0.f);
  // Half the source are noisy copies, half are copies of a few targets (ambiguous).
  for (int i = 0; i < 100; ++i)
    add(source, flipped(target.descriptors[i % 50 < 25 ? i : i % 5], (i * 7) % 240, 12),
        static_cast<float>(i), 0.f);
  pcl::rast::HammingMatchParams strict;
  strict.spatial_gate_radius_m = 60.0;
  pcl::Correspondences nearest;
  const pcl::Correspondences matches =
      pcl::rast::matchHamming(source, target, strict, Eigen::Isometry3d::Identity(), &nearest);
  pcl::rast::HammingMatchParams loose = strict;
  loose.ratio = 1.0;
  loose.mutual_check = false;
  const pcl::Correspondences expected = pcl::rast::matchHamming(source, target, loose);
  ASSERT_EQ(nearest.size(), expected.size());
  for (std::size_t k = 0; k < nearest.size(); ++k) {
    EXPECT_EQ(nearest[k].index_query, expected[k].index_query);
    EXPECT_EQ(nearest[k].index_match, expected[k].index_match);
    EXPECT_FLOAT_EQ(nearest[k].distance, expected[k].distance);
  }
  EXPECT_LT(matches.size(), nearest.size()); // the ratio test and mutual check dropped some
}

TEST(HammingCorrespondenceEstimation, MaxHammingDistance)
{
  RasterFeatureSet source, target;
  add(target, withBits(0));
  add(source, withBits(30));
  HammingMatchParams params;
  params.max_hamming_distance = 29;
  EXPECT_TRUE(pcl::rast::matchHamming(source, target, params).empty());
  params.max_hamming_distance = 30;
  EXPECT_EQ(pcl::rast::matchHamming(source, target, params).size(), 1u);
}

TEST(HammingCorrespondenceEstimation, RatioTestRejectsAmbiguousMatches)
{
  RasterFeatureSet source, target;
  add(source, withBits(0));
  add(target, flipped(withBits(0), 0, 20));   // distance 20
  add(target, flipped(withBits(0), 100, 22)); // distance 22: ambiguous
  HammingMatchParams params;
  params.mutual_check = false;
  params.ratio = 0.8;
  EXPECT_TRUE(pcl::rast::matchHamming(source, target, params).empty());
  params.ratio = 1.0; // disabled
  const auto c = pcl::rast::matchHamming(source, target, params);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].index_match, 0);

  // A distinctive best match passes: 10 < 0.8 * 22.
  target.descriptors[0] = flipped(withBits(0), 0, 10);
  params.ratio = 0.8;
  EXPECT_EQ(pcl::rast::matchHamming(source, target, params).size(), 1u);
}

TEST(HammingCorrespondenceEstimation, MutualCheckKeepsOnlyCrossConsistentPairs)
{
  // Both sources prefer target 0, but target 0 prefers source 1.
  RasterFeatureSet source, target;
  add(target, withBits(0));
  add(target, flipped(withBits(0), 200, 56)); // far from both sources
  add(source, flipped(withBits(0), 0, 12));   // source 0: distance 12 to target 0
  add(source, flipped(withBits(0), 50, 5));   // source 1: distance 5 to target 0
  HammingMatchParams params;
  params.ratio = 1.0;
  params.mutual_check = false;
  EXPECT_EQ(pcl::rast::matchHamming(source, target, params).size(), 2u);
  params.mutual_check = true;
  const auto c = pcl::rast::matchHamming(source, target, params);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].index_query, 1);
  EXPECT_EQ(c[0].index_match, 0);
}

TEST(HammingCorrespondenceEstimation, SpatialGateUsesTheInitialGuess)
{
  // Two targets with the same descriptor, 10 m apart; the guess decides.
  RasterFeatureSet source, target;
  add(target, withBits(40), 0.f, 0.f);
  add(target, withBits(40), 10.f, 0.f);
  add(source, withBits(40), 0.f, 0.f);
  HammingMatchParams params;
  params.spatial_gate_radius_m = 1.0;
  Eigen::Isometry3d guess = Eigen::Isometry3d::Identity();
  guess.translation() = Eigen::Vector3d(10.2, 0.0, 0.0);
  auto c = pcl::rast::matchHamming(source, target, params, guess);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].index_match, 1);
  guess.translation() = Eigen::Vector3d(0.3, 0.0, 0.0);
  c = pcl::rast::matchHamming(source, target, params, guess);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].index_match, 0);
  guess.translation() = Eigen::Vector3d(5.0, 0.0, 0.0); // nothing within 1 m
  EXPECT_TRUE(pcl::rast::matchHamming(source, target, params, guess).empty());
  // Without the gate the two equal candidates are ambiguous for the ratio test.
  params.spatial_gate_radius_m = 0.0;
  EXPECT_TRUE(pcl::rast::matchHamming(source, target, params, guess).empty());
}

/// Features as the PCL estimator sees them: ORBSignature256 clouds.
pcl::PointCloud<pcl::rast::ORBSignature256>::Ptr
signatures(const RasterFeatureSet& set)
{
  auto cloud = std::make_shared<pcl::PointCloud<pcl::rast::ORBSignature256>>();
  pcl::rast::toSignatureCloud(set, *cloud);
  return cloud;
}

TEST(HammingCorrespondenceEstimation, PclEstimatorEqualsMatchHamming)
{
  std::mt19937 rng(57);
  RasterFeatureSet source, target;
  for (int i = 0; i < 60; ++i) {
    const OrbDescriptor d = randomDescriptor(rng);
    add(source, d, float(i));
    add(target, flipped(d, i % 200, 10 + i % 30), float(i));
  }
  for (int i = 0; i < 20; ++i)
    add(target, randomDescriptor(rng));
  pcl::registration::CorrespondenceEstimationBase<pcl::rast::ORBSignature256,
                                                  pcl::rast::ORBSignature256>::Ptr
      estimation(new pcl::rast::HammingCorrespondenceEstimation);
  estimation->setInputSource(signatures(source));
  estimation->setInputTarget(signatures(target));
  pcl::Correspondences through_pcl;
  estimation->determineCorrespondences(through_pcl);
  const pcl::Correspondences direct = pcl::rast::matchHamming(source, target);
  ASSERT_GT(direct.size(), 30u);
  ASSERT_EQ(through_pcl.size(), direct.size());
  for (std::size_t k = 0; k < direct.size(); ++k) {
    EXPECT_EQ(through_pcl[k].index_query, direct[k].index_query);
    EXPECT_EQ(through_pcl[k].index_match, direct[k].index_match);
    EXPECT_EQ(through_pcl[k].distance, direct[k].distance);
  }

  // max_distance tightens the Hamming bound.
  pcl::Correspondences close;
  estimation->determineCorrespondences(close, 20.0);
  ASSERT_FALSE(close.empty());
  EXPECT_LT(close.size(), direct.size());
  for (const auto& c : close)
    EXPECT_LE(c.distance, 20.0f);

  // A clone matches the same way; reciprocal matching is the mutual check.
  auto clone = estimation->clone();
  pcl::Correspondences reciprocal;
  clone->determineReciprocalCorrespondences(reciprocal);
  EXPECT_EQ(reciprocal.size(), direct.size()); // the default params check mutually
}

TEST(HammingCorrespondenceEstimation, PclEstimatorHonoursIndices)
{
  std::mt19937 rng(58);
  RasterFeatureSet set;
  for (int i = 0; i < 40; ++i)
    add(set, randomDescriptor(rng), float(i));
  pcl::rast::HammingCorrespondenceEstimation estimation;
  estimation.setInputSource(signatures(set));
  estimation.setInputTarget(signatures(set));
  auto odd = std::make_shared<pcl::Indices>();
  for (int i = 1; i < 40; i += 2)
    odd->push_back(i);
  estimation.setIndices(odd);
  estimation.setIndicesTarget(odd);
  pcl::Correspondences c;
  estimation.determineCorrespondences(c);
  ASSERT_EQ(c.size(), odd->size());
  for (const auto& m : c) {
    EXPECT_EQ(m.index_query % 2, 1) << "source index outside the given indices";
    EXPECT_EQ(m.index_match, m.index_query);
  }
  odd->push_back(99);
  EXPECT_THROW(estimation.determineCorrespondences(c), std::out_of_range);
}

TEST(HammingCorrespondenceEstimation, ValidationNamesTheBadValue)
{
  pcl::rast::HammingCorrespondenceEstimation estimation;
  pcl::Correspondences c;
  EXPECT_THROW(estimation.determineCorrespondences(c), std::invalid_argument);

  RasterFeatureSet source;
  add(source, withBits(3));
  source.descriptors.push_back(withBits(1)); // points and descriptors now differ
  EXPECT_THROW(pcl::rast::matchHamming(source, source), std::invalid_argument);

  HammingMatchParams bad;
  bad.ratio = 1.5;
  std::string why;
  EXPECT_FALSE(bad.isValid(&why));
  EXPECT_NE(why.find("ratio"), std::string::npos);
  EXPECT_THROW(estimation.setParams(bad), std::invalid_argument);
  bad = HammingMatchParams();
  bad.max_hamming_distance = 300;
  EXPECT_FALSE(bad.isValid());
  bad = HammingMatchParams();
  bad.spatial_gate_radius_m = -1.0;
  source.descriptors.pop_back();
  EXPECT_THROW(pcl::rast::matchHamming(source, source, bad), std::invalid_argument);
}

} // namespace

} // namespace test_hamming_correspondence_estimation
