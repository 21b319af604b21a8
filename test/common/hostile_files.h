#pragma once
/// \file hostile_files.h
/// \brief Scan and pose files that lie (issue 12), made in memory from good files: PCD
/// headers with impossible counts and sizes on each body kind, corrupt compressed and
/// truncated bodies, words where numbers belong, lying PLY headers, short .bin files,
/// and pose files that are not poses. The reader tests (test_hostile_inputs.cpp) and
/// the tool tests (test_hostile_tools.cpp) share them.

#include "random_cloud.h"
#include "test_data.h"

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace pcl_rast_test {

/// \a text with the first occurrence of \a from replaced by \a to (which must exist).
inline std::string
replaced(std::string text, const std::string& from, const std::string& to)
{
  const std::size_t at = text.find(from);
  if (at == std::string::npos)
    throw std::runtime_error("'" + from + "' not in the good file");
  return text.replace(at, from.size(), to);
}

/// The good files the mutations start from, as bytes, by name.
struct GoodFiles
{
  std::string pcd_ascii, pcd_binary, pcd_compressed, ply_ascii, ply_binary;
};

inline GoodFiles
makeGoodFiles(const std::filesystem::path& dir)
{
  const pcl::PointCloud<pcl::PointXYZI> cloud = randomCloud(200, 7);
  const auto saved = [&](int status, const char* name) {
    if (status != 0)
      throw std::runtime_error(std::string("cannot write the good file ") + name);
  };
  saved(pcl::io::savePCDFileASCII((dir / "good_a.pcd").string(), cloud), "good_a.pcd");
  saved(pcl::io::savePCDFileBinary((dir / "good_b.pcd").string(), cloud), "good_b.pcd");
  saved(pcl::io::savePCDFileBinaryCompressed((dir / "good_c.pcd").string(), cloud),
        "good_c.pcd");
  saved(pcl::io::savePLYFileASCII((dir / "good_a.ply").string(), cloud), "good_a.ply");
  saved(pcl::io::savePLYFileBinary((dir / "good_b.ply").string(), cloud), "good_b.ply");
  return {readFile(dir / "good_a.pcd"),
          readFile(dir / "good_b.pcd"),
          readFile(dir / "good_c.pcd"),
          readFile(dir / "good_a.ply"),
          readFile(dir / "good_b.ply")};
}

/// One hostile file: its name and bytes.
struct Hostile
{
  std::string name;
  std::string bytes;
};

/// Header lies applied to each kind of PCD body.
inline std::vector<Hostile>
pcdHeaderLies(const GoodFiles& good)
{
  const std::vector<std::pair<std::string, std::string>> kinds = {
      {"ascii", good.pcd_ascii},
      {"binary", good.pcd_binary},
      {"compressed", good.pcd_compressed}};
  const std::vector<std::pair<std::string, std::pair<std::string, std::string>>> lies = {
      {"count_negative", {"COUNT 1 1 1 1", "COUNT -1 1 1 1"}},
      {"count_2p30", {"COUNT 1 1 1 1", "COUNT 1073741824 1 1 1"}},
      {"count_zero", {"COUNT 1 1 1 1", "COUNT 0 1 1 1"}},
      {"size_negative", {"SIZE 4 4 4 4", "SIZE -1 4 4 4"}},
      {"size_3", {"SIZE 4 4 4 4", "SIZE 3 4 4 4"}},
      {"size_float16", {"SIZE 4 4 4 4", "SIZE 2 4 4 4"}},
      {"type_unknown", {"TYPE F F F F", "TYPE X F F F"}},
      {"fields_short", {"SIZE 4 4 4 4", "SIZE 4 4 4"}},
      {"width_2p28", {"WIDTH 200", "WIDTH 268435456"}},
      {"width_negative", {"WIDTH 200", "WIDTH -5"}},
      {"width_above_2p32", {"WIDTH 200", "WIDTH 99999999999"}},
      {"points_mismatch", {"POINTS 200", "POINTS 7"}},
      {"fields_twice", {"SIZE 4 4 4 4", "FIELDS a b c d\nSIZE 4 4 4 4"}},
      {"no_xyz", {"FIELDS x y z intensity", "FIELDS a b c intensity"}},
      {"unknown_key", {"VIEWPOINT", "FROBNICATE 3\nVIEWPOINT"}},
      {"header_line_70k", {"VIEWPOINT", "# " + std::string(70000, 'x') + "\nVIEWPOINT"}},
  };
  std::vector<Hostile> files;
  for (const auto& [kind, bytes] : kinds)
    for (const auto& [lie, edit] : lies)
      files.push_back(
          {"pcd_" + kind + "_" + lie + ".pcd", replaced(bytes, edit.first, edit.second)});
  return files;
}

/// Bodies that do not match a truthful header.
inline std::vector<Hostile>
pcdBodyLies(const GoodFiles& good)
{
  std::vector<Hostile> files;
  const std::size_t data_c = good.pcd_compressed.find("DATA binary_compressed\n") + 23;
  auto sizes = [&](std::uint32_t compressed, std::uint32_t uncompressed) {
    std::string b = good.pcd_compressed;
    std::memcpy(&b[data_c], &compressed, 4);
    std::memcpy(&b[data_c + 4], &uncompressed, 4);
    return b;
  };
  files.push_back({"pcd_compressed_sizes_zero.pcd", sizes(0, 0)});
  files.push_back({"pcd_compressed_sizes_garbage.pcd", sizes(0xFFFFFFF0u, 0xFFFFFFF0u)});
  files.push_back({"pcd_compressed_uncompressed_lies.pcd", sizes(100, 200 * 16 + 4)});
  std::string scrambled = good.pcd_compressed;
  std::fill(scrambled.begin() + static_cast<long>(data_c) + 8, scrambled.end(), '\xFF');
  files.push_back({"pcd_compressed_scrambled.pcd", scrambled});
  files.push_back(
      {"pcd_compressed_no_sizes.pcd", good.pcd_compressed.substr(0, data_c + 5)});
  files.push_back({"pcd_binary_one_byte_short.pcd",
                   good.pcd_binary.substr(0, good.pcd_binary.size() - 1)});
  files.push_back(
      {"pcd_binary_no_data_line.pcd",
       replaced(good.pcd_binary.substr(0, 200), "DATA binary", "DATUM binary")});
  files.push_back(
      {"pcd_data_kind_unknown.pcd", replaced(good.pcd_ascii, "DATA ascii", "DATA text")});
  // Words where numbers belong: PCL's reader loads these as points at the origin.
  const std::size_t data_a = good.pcd_ascii.find("DATA ascii\n") + 11;
  std::string words = good.pcd_ascii.substr(0, data_a);
  for (int i = 0; i < 200; ++i)
    words += "the quick brown fox\n";
  files.push_back({"pcd_ascii_words.pcd", words});
  files.push_back(
      {"pcd_ascii_missing_value.pcd",
       good.pcd_ascii.substr(0, data_a) + "1 2 3\n" + good.pcd_ascii.substr(data_a)});
  files.push_back({"pcd_ascii_fewer_lines.pcd", good.pcd_ascii.substr(0, data_a + 40)});
  files.push_back({"pcd_ascii_integer_fraction.pcd",
                   replaced(replaced(good.pcd_ascii, "TYPE F F F F", "TYPE F F F U"),
                            "SIZE 4 4 4 4",
                            "SIZE 4 4 4 1")});
  return files;
}

inline std::vector<Hostile>
plyLies(const GoodFiles& good)
{
  std::vector<Hostile> files;
  const std::vector<std::pair<std::string, std::pair<std::string, std::string>>> lies = {
      {"vertex_2p32", {"element vertex 200", "element vertex 4294967296"}},
      {"vertex_99999999999", {"element vertex 200", "element vertex 99999999999"}},
      {"vertex_negative", {"element vertex 200", "element vertex -1"}},
      {"vertex_more_than_data", {"element vertex 200", "element vertex 3000000"}},
      {"list_on_vertex", {"property float x", "property list uint float x"}},
      {"unknown_type", {"property float x", "property float128 x"}},
      {"no_format", {"format ", "comment "}},
      {"no_end_header", {"end_header", "end_hedder"}},
      {"face_first",
       {"element vertex 200",
        "element face 4294967295\nproperty list uchar int "
        "vertex_indices\nelement vertex 200"}},
      {"no_vertex", {"element vertex 200", "element point 200"}},
      {"magic", {"ply", "plz"}},
  };
  for (const auto& [kind, bytes] : std::vector<std::pair<std::string, std::string>>{
           {"ascii", good.ply_ascii}, {"binary", good.ply_binary}})
    for (const auto& [lie, edit] : lies)
      files.push_back(
          {"ply_" + kind + "_" + lie + ".ply", replaced(bytes, edit.first, edit.second)});
  const std::size_t end = good.ply_ascii.find("end_header\n") + 11;
  files.push_back({"ply_ascii_words.ply",
                   good.ply_ascii.substr(0, end) + std::string(200 * 20, 'w') + "\n"});
  files.push_back(
      {"ply_binary_truncated.ply",
       good.ply_binary.substr(0, good.ply_binary.find("end_header\n") + 11 + 100)});
  files.push_back(
      {"ply_big_endian_truncated.ply",
       replaced(good.ply_binary.substr(0, good.ply_binary.find("end_header\n") + 11 + 30),
                "binary_little_endian",
                "binary_big_endian")});
  return files;
}

inline std::vector<Hostile>
binLies()
{
  return {{"bin_17_bytes.bin", std::string(17, '\x01')},
          {"bin_15_bytes.bin", std::string(15, '\x01')},
          {"bin_text.bin", "not a float scan at all\n"}};
}

/// Every lying scan file: PCD header and body lies, PLY lies and short .bin files.
inline std::vector<Hostile>
allScanLies(const GoodFiles& good)
{
  std::vector<Hostile> files = pcdHeaderLies(good);
  for (const std::vector<Hostile>& more : {pcdBodyLies(good), plyLies(good), binLies()})
    files.insert(files.end(), more.begin(), more.end());
  return files;
}

/// Pose files (KITTI or TUM) that are not poses: wrong column counts, words, NaN and
/// overflowing numbers, rotations that are not rotations, zero quaternions, binary
/// bytes, a line without end, and files with no pose at all.
inline std::vector<Hostile>
poseLies()
{
  const std::string kitti_row = "1 0 0 0 0 1 0 0 0 0 1 0\n";
  const std::string tum_row = "0.0 0 0 0 0 0 0 1\n";
  return {
      {"poses_empty.txt", ""},
      {"poses_comments_only.txt", "# nothing here\n\n"},
      {"poses_kitti_11_numbers.txt", kitti_row + "1 0 0 0 0 1 0 0 0 0 1\n"},
      {"poses_kitti_13_numbers.txt", kitti_row + "1 0 0 0 0 1 0 0 0 0 1 0 5\n"},
      {"poses_kitti_word.txt", kitti_row + "1 0 0 x 0 1 0 0 0 0 1 0\n"},
      {"poses_kitti_nan.txt", kitti_row + "1 0 0 nan 0 1 0 0 0 0 1 0\n"},
      {"poses_kitti_inf.txt", kitti_row + "1 0 0 inf 0 1 0 0 0 0 1 0\n"},
      {"poses_kitti_overflow.txt", kitti_row + "1 0 0 1e999 0 1 0 0 0 0 1 0\n"},
      {"poses_kitti_scaled.txt", kitti_row + "2 0 0 0 0 2 0 0 0 0 2 0\n"},
      {"poses_kitti_reflection.txt", kitti_row + "-1 0 0 0 0 1 0 0 0 0 1 0\n"},
      {"poses_kitti_zero_rotation.txt", kitti_row + "0 0 0 0 0 0 0 0 0 0 0 0\n"},
      {"poses_tum_zero_quaternion.txt", tum_row + "0.1 1 0 0 0 0 0 0\n"},
      {"poses_tum_nan_quaternion.txt", tum_row + "0.1 1 0 0 nan 0 0 1\n"},
      {"poses_tum_nan_time.txt", tum_row + "nan 1 0 0 0 0 0 1\n"},
      {"poses_mixed_formats.txt", kitti_row + tum_row},
      {"poses_binary.txt",
       std::string("\x7f"
                   "ELF\x02\x01\x01\0\0\0\xff\xfe\n",
                   13)},
      {"poses_line_2mib.txt", std::string(2u << 20, '1')},
      {"poses_zeros_2mib.txt", std::string(2u << 20, '\0')},
  };
}

} // namespace pcl_rast_test
