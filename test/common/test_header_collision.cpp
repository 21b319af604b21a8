// Our public headers must coexist with PCL 1.13's: every header of ours is
// included here next to PCL's module headers (a clash of include guards, class
// names or point-type registrations fails to compile), and none of our header
// paths may exist in PCL's own include tree (it would shadow or be shadowed).
#include "pcl_rast_all_headers.h"

#include <pcl/features/normal_3d.h>
#include <pcl/features/feature.h>
#include <pcl/registration/correspondence_estimation.h>
#include <pcl/registration/correspondence_rejection_sample_consensus.h>
#include <pcl/registration/transformation_estimation_svd.h>
#include <pcl/segmentation/sac_segmentation.h>
#include <pcl/range_image/range_image.h>

#include <gtest/gtest.h>

#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

namespace {

std::vector<std::string>
split(const std::string& text)
{
  std::vector<std::string> parts;
  std::stringstream stream(text);
  std::string part;
  while (std::getline(stream, part, '|'))
    if (!part.empty())
      parts.push_back(part);
  return parts;
}

} // namespace

TEST(HeaderCollision, NoHeaderPathExistsInPclIncludeTree)
{
  const auto ours = split(PCL_RAST_PUBLIC_HEADERS);
  const auto pcl_dirs = split(PCL_SYSTEM_INCLUDE_DIRS);
  ASSERT_FALSE(ours.empty());
  ASSERT_FALSE(pcl_dirs.empty());
  bool found_pcl_tree = false;
  for (const auto& dir : pcl_dirs) {
    if (!std::filesystem::exists(std::filesystem::path(dir) / "pcl/pcl_config.h"))
      continue;
    found_pcl_tree = true;
    for (const auto& header : ours)
      EXPECT_FALSE(std::filesystem::exists(std::filesystem::path(dir) / header))
          << header << " also exists in PCL's include tree " << dir;
  }
  EXPECT_TRUE(found_pcl_tree) << "PCL's include tree was not found in " << PCL_SYSTEM_INCLUDE_DIRS;
}

TEST(HeaderCollision, OurTypesAndPclTypesCoexist)
{
  pcl::rast::RasterFeatureSet features;
  pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> normals;
  pcl::registration::TransformationEstimationSVD<pcl::PointXYZ, pcl::PointXYZ> svd;
  EXPECT_TRUE(features.empty());
  (void)normals;
  (void)svd;
}
