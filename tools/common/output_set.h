#pragma once
/// \file output_set.h
/// \brief The output folder of a run as one all-or-nothing set (issue 12, doc/slam.md
/// "Output sets"). A run writes every file into a staging folder inside the output
/// folder; publish() then moves them into place and writes summary.json last, which
/// lists each file with its size and CRC-32 and the run's id. Until publish() the
/// previous set is untouched: any failure or a second signal leaves it as it was.
/// publish() writes a copy of the manifest into the staging folder before the first
/// move, so a run killed while publishing is completed by the next one (roll forward);
/// checkOutputSet() tells a complete set from a mixed one.

#include <pcl/rast/file_checksum.h>

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace pcl_rast_tools {

/// \brief Creates \a dir when missing and checks that files can be written in it.
/// \throws std::runtime_error naming the folder and the cause.
void checkWritableFolder(const std::string& dir);

/// \brief Refuse an output folder that is the scan folder: the next run would read the
/// map and poses written there as scans.
/// \throws std::invalid_argument naming both.
void checkOutputIsNotInput(const std::string& output, const std::string& scan_folder);

/// The CRC-32 of a file (common: pcl/rast/file_checksum.h), as output sets list it.
using pcl::rast::fileCrc32;

/// \brief What checkOutputSet() found.
struct OutputSetCheck
{
  bool has_manifest = false; ///< summary.json lists its files (written by this version)
  bool complete = false;     ///< every listed file is present with its size and CRC
  std::string run_id;
  std::vector<std::string> problems; ///< one line per missing or mismatched file
};

/// \brief Check the output set in \a dir against its summary.json.
OutputSetCheck checkOutputSet(const std::string& dir);

/// \brief The files of one run, staged and then published together.
class OutputSet
{
public:
  /// \brief Prepare \a dir (created when missing, checked writable), complete a publish
  /// that an earlier run could not finish, and make a fresh staging folder.
  /// \throws std::runtime_error when the folder cannot be used.
  OutputSet(const std::string& dir, const std::string& tool);
  /// Removes the staging folder when the set was not published.
  ~OutputSet();
  OutputSet(const OutputSet&) = delete;
  OutputSet& operator=(const OutputSet&) = delete;

  /// \brief Where the run writes its file \a name (inside the staging folder).
  std::string path(const std::string& name) const;

  /// \brief The folder the set is published to.
  const std::string& folder() const { return dir_; }

  /// \brief This run's id (UTC time, process id).
  const std::string& runId() const { return run_id_; }

  /// \brief Add "output_set" (run id, files with sizes and CRCs) to \a summary, then
  /// move every staged file into the folder and summary.json last.
  /// \throws std::runtime_error naming the cause; the previous set is then intact
  /// unless the failure came after the first move (a later run completes it).
  void publish(nlohmann::json& summary);

private:
  std::string dir_, tool_, run_id_, staging_;
  bool published_ = false;
};

} // namespace pcl_rast_tools
