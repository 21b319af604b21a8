#pragma once
/// \file stop_signals.h
/// \brief How every long-running tool ends on a signal (issue 12): SIGINT, SIGTERM and
/// SIGHUP ask it to stop; it finishes or drops the current frame and writes complete
/// outputs. A second such signal ends the process at once (exit 128 + signal) without
/// touching the last complete output set. SIGPIPE is ignored: a closed pipe on stderr
/// (`pcl_rast_slam ... 2>&1 | head`) fails those writes instead of killing the run, and
/// so is SIGXFSZ: a file size limit fails the write with an error that names it.

#include <cstddef>

namespace pcl_rast_tools {

/// \brief Install the handlers. Call once, before the work starts.
void installStopSignals();

/// \brief Whether a stop was asked for (async-signal-safe flag).
bool stopRequested();

/// \brief The signal that asked for the stop (SIGINT, SIGTERM, SIGHUP), or 0.
int stopSignal();

/// \brief The signal's name ("SIGTERM"), or "" when none came.
const char* stopSignalName();

/// \brief While one lives, a second stop signal does not end the process at once: the
/// exit (128 + signal) waits until it is destroyed. OutputSet::publish holds one while
/// it moves the files into place (a few renames), so the folder holds the complete new
/// set, not a mix, when the process ends.
class DeferStopExit
{
public:
  DeferStopExit();
  ~DeferStopExit();
  DeferStopExit(const DeferStopExit&) = delete;
  DeferStopExit& operator=(const DeferStopExit&) = delete;
};

/// \brief Tell the user on stderr that \a tool stops after \a frames on the signal and
/// writes what it has.
void reportStop(const char* tool, std::size_t frames);

} // namespace pcl_rast_tools
