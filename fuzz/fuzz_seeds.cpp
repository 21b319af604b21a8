/// \file fuzz_seeds.cpp
/// \brief Writes the fuzz harnesses' seed corpora from the real data in ../shared/data:
/// small valid scans in every format (a few hundred points of real scans, also with a
/// time field and organized), and the first lines of real pose, times and g2o files.
///
///   fuzz_seeds SHARED_DATA_DIR CORPUS_DIR    (writes CORPUS_DIR/<harness>/...)

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/io/sequence_reader.h>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

struct EIGEN_ALIGN16 PointXYZIT
{
  PCL_ADD_POINT4D;
  float intensity;
  float time;
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};

/// Every k-th point of \a cloud, at most \a n.
pcl::PointCloud<pcl::PointXYZI>
thin(const pcl::PointCloud<pcl::PointXYZI>& cloud, std::size_t n)
{
  pcl::PointCloud<pcl::PointXYZI> out;
  const std::size_t step = std::max<std::size_t>(1, cloud.size() / n);
  for (std::size_t i = 0; i < cloud.size() && out.size() < n; i += step)
    out.push_back(cloud[i]);
  return out;
}

void
copyHead(const fs::path& from, const fs::path& to, int lines)
{
  std::ifstream in(from);
  std::ofstream out(to);
  std::string line;
  for (int i = 0; i < lines && std::getline(in, line); ++i)
    out << line << "\n";
}

} // namespace

POINT_CLOUD_REGISTER_POINT_STRUCT(PointXYZIT,
                                  (float, x, x)(float, y, y)(float, z, z)(
                                      float, intensity, intensity)(float, time, time))

int
main(int argc, char** argv)
{
  if (argc != 3) {
    std::fprintf(stderr, "usage: fuzz_seeds SHARED_DATA_DIR CORPUS_DIR\n");
    return 1;
  }
  const fs::path data(argv[1]), corpus(argv[2]);
  for (const char* h : {"pcd", "ply", "bin", "poses", "times", "calib", "g2o"})
    fs::create_directories(corpus / h);
  const std::vector<fs::path> scans = {data / "kitti-raw-78" / "velodyne" /
                                           "0000000000.bin",
                                       data / "kitti-raw-22" / "pcd" / "0000000000.pcd",
                                       data / "scan-pair-ply" / "source.ply",
                                       data / "scan-pair-pcd" / "251370668.pcd"};
  int k = 0;
  for (const fs::path& scan : scans) {
    if (!fs::exists(scan))
      continue;
    const auto small = thin(*pcl::rast::readScan(scan.string()), 300);
    const std::string n = std::to_string(k++);
    pcl::io::savePCDFileASCII((corpus / "pcd" / ("a" + n + ".pcd")).string(), small);
    pcl::io::savePCDFileBinary((corpus / "pcd" / ("b" + n + ".pcd")).string(), small);
    pcl::io::savePCDFileBinaryCompressed((corpus / "pcd" / ("c" + n + ".pcd")).string(),
                                         small);
    pcl::io::savePLYFileASCII((corpus / "ply" / ("a" + n + ".ply")).string(), small);
    pcl::io::savePLYFileBinary((corpus / "ply" / ("b" + n + ".ply")).string(), small);
    pcl::rast::writeKittiBin((corpus / "bin" / (n + ".bin")).string(), small);
    // With a time field, and organized 10 x 30, as raw sweeps are.
    pcl::PointCloud<PointXYZIT> timed;
    for (std::size_t i = 0; i < small.size(); ++i) {
      PointXYZIT p;
      p.getVector4fMap() = small[i].getVector4fMap();
      p.intensity = small[i].intensity;
      p.time = 0.1f * static_cast<float>(i) / static_cast<float>(small.size());
      timed.push_back(p);
    }
    if (timed.size() == 300) {
      timed.width = 30;
      timed.height = 10;
    }
    pcl::io::savePCDFileBinary((corpus / "pcd" / ("t" + n + ".pcd")).string(), timed);
    pcl::io::savePLYFileBinary((corpus / "ply" / ("t" + n + ".ply")).string(), timed);
  }
  copyHead(data / "kitti-gt-poses" / "00.txt", corpus / "poses" / "kitti.txt", 40);
  copyHead(data / "kitti-gt-poses" / "00_times.txt", corpus / "times" / "times.txt", 40);
  copyHead(
      data / "pose-graph-g2o" / "parking-garage.g2o", corpus / "g2o" / "head.g2o", 60);
  std::ofstream(corpus / "poses" / "tum.txt")
      << "# timestamp tx ty tz qx qy qz qw\n0.0 0 0 0 0 0 0 1\n0.1 1.5 0.01 0 0 0 0.0998 "
         "0.995\n";
  std::ofstream(corpus / "calib" / "calib.txt")
      << "P0: 7.18e+02 0 6.07e+02 0 0 7.18e+02 1.85e+02 0 0 0 1 0\n"
         "Tr: 4.27e-04 -9.99e-01 -8.08e-03 -1.19e-02 -7.21e-03 8.08e-03 -9.99e-01 "
         "-5.40e-02 9.99e-01 4.85e-04 -7.21e-03 -2.92e-01\n";
  std::printf("seed corpus written to %s\n", corpus.string().c_str());
  return 0;
}
