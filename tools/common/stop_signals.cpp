/// \file stop_signals.cpp
/// \brief SIGINT/SIGTERM/SIGHUP as stop requests, SIGPIPE ignored (stop_signals.h).

#include "stop_signals.h"

#include <atomic>
#include <csignal>
#include <cstdio>
#include <initializer_list>
#include <unistd.h>

namespace pcl_rast_tools {

namespace {

std::atomic<int> g_stop_signal{0};
std::atomic<bool> g_defer_exit{false};   ///< a DeferStopExit lives (outputs moving)
std::atomic<int> g_deferred_signal{0};   ///< a second signal that came meanwhile
static_assert(std::atomic<int>::is_always_lock_free && std::atomic<bool>::is_always_lock_free,
              "the handler needs lock-free flags");

extern "C" void
onStopSignal(int signal_number)
{
  // A second signal: the user means it. _exit is async-signal-safe and runs no
  // destructors, so no half-written file is renamed over a complete one. While the
  // outputs are being moved into place it waits for the last rename (DeferStopExit):
  // ending there would leave half the new set beside half the old one.
  int expected = 0;
  if (g_stop_signal.compare_exchange_strong(expected, signal_number))
    return;
  if (g_defer_exit.load()) {
    g_deferred_signal.store(signal_number);
    return;
  }
  ::_exit(128 + signal_number);
}

} // namespace

void
installStopSignals()
{
  struct sigaction action = {};
  action.sa_handler = onStopSignal;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESTART; // blocking reads and writes go on after the handler
  for (int s : {SIGINT, SIGTERM, SIGHUP})
    sigaction(s, &action, nullptr);
  struct sigaction ignore = {};
  ignore.sa_handler = SIG_IGN;
  sigemptyset(&ignore.sa_mask);
  sigaction(SIGPIPE, &ignore, nullptr);
  // A file size limit (ulimit -f) fails the write with EFBIG, named in the error, and
  // leaves the previous outputs, instead of killing the process.
  sigaction(SIGXFSZ, &ignore, nullptr);
}

bool
stopRequested()
{
  return g_stop_signal.load() != 0;
}

int
stopSignal()
{
  return g_stop_signal.load();
}

const char*
stopSignalName()
{
  switch (g_stop_signal.load()) {
  case SIGINT:
    return "SIGINT";
  case SIGTERM:
    return "SIGTERM";
  case SIGHUP:
    return "SIGHUP";
  default:
    return "";
  }
}

void
reportStop(const char* tool, std::size_t frames)
{
  std::fprintf(stderr,
               "\n%s: %s after %zu frames; writing the results so far (a second signal ends "
               "at once and keeps the previous output)\n",
               tool, stopSignalName(), frames);
}

DeferStopExit::DeferStopExit()
{
  g_defer_exit.store(true);
}

DeferStopExit::~DeferStopExit()
{
  g_defer_exit.store(false);
  if (const int s = g_deferred_signal.load())
    ::_exit(128 + s);
}

} // namespace pcl_rast_tools
