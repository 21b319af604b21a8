/// \file output_set.cpp
/// \brief Staged, all-or-nothing output folders (output_set.h).

#include "output_set.h"
#include "stop_signals.h"

#include <algorithm>
#include <pcl/rast/file_checksum.h>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <pcl/rast/atomic_file.h>
#include <stdexcept>
#include <system_error>
#include <unistd.h>

namespace fs = std::filesystem;

namespace pcl_rast_tools {

namespace {

constexpr const char* kStagingPrefix = ".pcl_rast_staging-";
constexpr const char* kSummary = "summary.json";

/// Make the renames into \a dir durable (a crash after publish keeps them).
void
syncFolder(const std::string& dir)
{
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd >= 0) {
    ::fsync(fd);
    ::close(fd);
  }
}

/// The process id in a staging folder's name, or 0.
long
stagingPid(const std::string& name)
{
  const std::size_t dash = name.rfind('-');
  if (dash == std::string::npos)
    return 0;
  try {
    return std::stol(name.substr(dash + 1));
  } catch (const std::exception&) {
    return 0;
  }
}

/// The "output_set" entry of dir/summary.json (run id, files with sizes and CRCs), or
/// null with \a why set when there is none or it cannot be read.
nlohmann::json
readManifest(const fs::path& dir, std::string& why)
{
  nlohmann::json summary;
  try {
    std::ifstream in(dir / kSummary);
    if (!in) {
      why = "no summary.json";
      return nullptr;
    }
    summary = nlohmann::json::parse(in);
  } catch (const std::exception& e) {
    why = std::string("summary.json does not parse: ") + e.what();
    return nullptr;
  }
  if (!summary.contains("output_set") || !summary["output_set"].contains("files") ||
      !summary["output_set"]["files"].is_array()) {
    why = "summary.json lists no files (written before output sets)";
    return nullptr;
  }
  return summary["output_set"];
}

/// The files the output set in \a dir lists (none without a readable manifest).
std::vector<std::string>
manifestNames(const fs::path& dir)
{
  std::string why;
  const nlohmann::json manifest = readManifest(dir, why);
  std::vector<std::string> names;
  if (!manifest.is_null())
    for (const nlohmann::json& f : manifest["files"])
      if (f.contains("name") && f["name"].is_string())
        names.push_back(f["name"].get<std::string>());
  return names;
}

/// Move every file of \a staging but summary.json into \a dir, remove the files of
/// the previous set that this one does not have (\a stale), then move summary.json.
void
moveIntoPlace(const fs::path& staging,
              const fs::path& dir,
              const std::vector<std::string>& stale = {})
{
  for (const fs::directory_entry& e : fs::directory_iterator(staging)) {
    const std::string name = e.path().filename().string();
    if (name != kSummary && e.is_regular_file())
      fs::rename(e.path(), dir / name);
  }
  for (const std::string& name : stale)
    if (fs::path(name).filename() == name) // a bare file name, never a path elsewhere
      fs::remove(dir / name);
  fs::rename(staging / kSummary, dir / kSummary);
  syncFolder(dir.string());
}

/// Finish publishing a set that an earlier run left half moved (it wrote the manifest
/// into its staging folder first), and remove staging folders of runs that died
/// before publishing. Folders of runs still alive are left alone.
void
recoverStaging(const fs::path& dir)
{
  std::error_code ec;
  for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind(kStagingPrefix, 0) != 0 || !e.is_directory())
      continue;
    const long pid = stagingPid(name);
    if (pid > 0 && pid != ::getpid() && ::kill(static_cast<pid_t>(pid), 0) == 0)
      continue; // another run is writing there
    if (fs::exists(e.path() / kSummary)) {
      std::fprintf(
          stderr, "Completing the output set that %s began to publish\n", name.c_str());
      moveIntoPlace(e.path(), dir);
    }
    fs::remove_all(e.path(), ec);
  }
}

std::string
makeRunId()
{
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y%m%dT%H%M%SZ", &utc);
  return std::string(stamp) + "-" + std::to_string(::getpid());
}

} // namespace

void
checkWritableFolder(const std::string& dir)
{
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (!fs::is_directory(dir))
    throw std::runtime_error("cannot create output folder " + dir +
                             (ec ? ": " + ec.message() : ""));
  const std::string probe =
      (fs::path(dir) / (".pcl_rast_write_test." + std::to_string(::getpid()))).string();
  errno = 0;
  std::FILE* f = std::fopen(probe.c_str(), "wb");
  if (!f)
    throw std::runtime_error("output folder " + dir +
                             " is not writable: " + std::strerror(errno));
  const bool ok = std::fputs("ok\n", f) >= 0;
  const bool closed = std::fclose(f) == 0;
  const int error = errno;
  std::remove(probe.c_str());
  if (!ok || !closed)
    throw std::runtime_error("output folder " + dir +
                             " is not writable: " + std::strerror(error));
}

void
checkOutputIsNotInput(const std::string& output, const std::string& scan_folder)
{
  std::error_code ec;
  if (fs::exists(output, ec) && fs::equivalent(output, scan_folder, ec))
    throw std::invalid_argument(
        "-output " + output + " is the scan folder " + scan_folder +
        ": the next run would read the map and poses written there "
        "as scans; choose another output folder");
}

OutputSetCheck
checkOutputSet(const std::string& dir)
{
  OutputSetCheck check;
  std::string why;
  const nlohmann::json manifest = readManifest(dir, why);
  if (manifest.is_null()) {
    check.problems.push_back(why);
    return check;
  }
  check.has_manifest = true;
  check.run_id = manifest.value("run_id", "");
  for (const nlohmann::json& f : manifest["files"]) {
    const std::string name = f.value("name", "");
    const fs::path path = fs::path(dir) / name;
    std::error_code ec;
    const auto size = fs::file_size(path, ec);
    if (ec) {
      check.problems.push_back(name + ": missing");
    } else if (size != f.value("size", std::uintmax_t{0})) {
      check.problems.push_back(name + ": " + std::to_string(size) +
                               " bytes, the run wrote " +
                               std::to_string(f.value("size", std::uintmax_t{0})));
    } else if (fileCrc32(path.string()) != f.value("crc32", "")) {
      check.problems.push_back(name + ": CRC-32 differs from the run's");
    }
  }
  check.complete = check.problems.empty();
  return check;
}

OutputSet::OutputSet(const std::string& dir, const std::string& tool)
    : dir_(dir), tool_(tool), run_id_(makeRunId())
{
  checkWritableFolder(dir_);
  recoverStaging(dir_);
  staging_ = (fs::path(dir_) / (kStagingPrefix + run_id_)).string();
  std::error_code ec;
  fs::create_directory(staging_, ec);
  if (ec)
    throw std::runtime_error("cannot create the staging folder " + staging_ + ": " +
                             ec.message());
}

OutputSet::~OutputSet()
{
  if (!published_) {
    std::error_code ec;
    fs::remove_all(staging_, ec);
  }
}

std::string
OutputSet::path(const std::string& name) const
{
  return (fs::path(staging_) / name).string();
}

void
OutputSet::publish(nlohmann::json& summary)
{
  nlohmann::json files = nlohmann::json::array();
  for (const fs::directory_entry& e : fs::directory_iterator(staging_)) {
    const std::string name = e.path().filename().string();
    if (!e.is_regular_file() || name == kSummary)
      continue;
    files.push_back({{"name", name},
                     {"size", fs::file_size(e.path())},
                     {"crc32", fileCrc32(e.path().string())}});
  }
  std::sort(
      files.begin(), files.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
        return a["name"].get<std::string>() < b["name"].get<std::string>();
      });
  summary["output_set"] = {{"run_id", run_id_}, {"tool", tool_}, {"files", files}};
  // Paths and messages may hold any bytes: invalid UTF-8 is replaced, never a throw.
  pcl::rast::writeFileAtomically(
      path(kSummary),
      summary.dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n");
  syncFolder(staging_);
  std::vector<std::string> stale; // files of the previous set that this run has not
  for (const std::string& name : manifestNames(dir_))
    if (std::none_of(files.begin(), files.end(), [&name](const nlohmann::json& f) {
          return f["name"] == name;
        }))
      stale.push_back(name);
  const DeferStopExit defer; // a second signal now ends the process after the moves
  try {
    moveIntoPlace(staging_, dir_, stale);
  } catch (const fs::filesystem_error& e) {
    throw std::runtime_error("cannot publish the outputs into " + dir_ + ": " +
                             e.code().message() + " (the next run completes them)");
  }
  published_ = true;
  std::error_code ec;
  fs::remove_all(staging_, ec);
}

} // namespace pcl_rast_tools
