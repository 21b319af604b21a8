/// \file map_render.cpp
/// \brief renderMapTopDown: VTK on the user's display, else on a private Xvfb, else
/// the OpenCV rasterizer; the overlays and an atomic PNG write either way.

#include "render_scene.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <poll.h>
#include <signal.h>
#include <sstream>
#include <stdexcept>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace pcl {
namespace rast {
namespace render_detail {

// ---------------------------------------------------------------------------
// Child processes: a private Xvfb and the VTK render.
// ---------------------------------------------------------------------------

/// Full path of an executable: \a name itself if it contains '/', else searched in PATH.
std::string
findExecutable(const std::string& name)
{
  if (name.find('/') != std::string::npos)
    return ::access(name.c_str(), X_OK) == 0 ? name : std::string();
  const char* path_env = std::getenv("PATH");
  std::stringstream dirs(path_env ? path_env : "/usr/local/bin:/usr/bin:/bin");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    const std::string candidate = (dir.empty() ? std::string(".") : dir) + "/" + name;
    if (::access(candidate.c_str(), X_OK) == 0)
      return candidate;
  }
  return {};
}

/// waitpid with a deadline; SIGKILL when it passes. Returns the wait status, or -1.
int
reapChild(pid_t pid, double grace_s)
{
  const pcl::StopWatch watch;
  int status = 0;
  while (true) {
    const pid_t r = ::waitpid(pid, &status, WNOHANG);
    if (r == pid)
      return status;
    if (r < 0 && errno != EINTR)
      return -1; // ECHILD: already reaped (e.g. SIGCHLD ignored)
    if (watch.getTimeSeconds() > grace_s) {
      ::kill(pid, SIGKILL);
      while (::waitpid(pid, &status, 0) < 0)
        if (errno != EINTR)
          return -1;
      return status;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

std::string
describeStatus(int status)
{
  if (status < 0)
    return "unknown status";
  if (WIFEXITED(status))
    return "exit code " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status))
    return std::string("signal ") + std::to_string(WTERMSIG(status)) + " (" +
           ::strsignal(WTERMSIG(status)) + ")";
  return "status " + std::to_string(status);
}

namespace {

/// Read from \a fd until a newline, end of file (\a eof) or \a timeout_s.
std::string
readLine(int fd, double timeout_s, bool& eof)
{
  std::string text;
  const pcl::StopWatch watch;
  eof = false;
  while (text.find('\n') == std::string::npos && !eof) {
    const double left_s = timeout_s - watch.getTimeSeconds();
    if (left_s <= 0.0)
      break;
    pollfd pfd{fd, POLLIN, 0};
    const int r = ::poll(&pfd, 1, static_cast<int>(std::ceil(left_s * 1000.0)));
    if (r < 0 && errno == EINTR)
      continue;
    if (r <= 0)
      break;
    char buf[64];
    const ssize_t n = ::read(fd, buf, sizeof(buf));
    if (n < 0 && errno == EINTR)
      continue;
    if (n <= 0)
      eof = true;
    else
      text.append(buf, static_cast<std::size_t>(n));
  }
  return text;
}

} // namespace

/// A private Xvfb server, stopped (SIGTERM, then SIGKILL) and reaped on destruction.
class PrivateXServer
{
public:
  PrivateXServer() = default;
  PrivateXServer(const PrivateXServer&) = delete;
  PrivateXServer& operator=(const PrivateXServer&) = delete;
  ~PrivateXServer() { stop(); }

  /// Start `Xvfb -displayfd` and wait until it reports its display (it is then ready).
  bool start(const std::string& executable,
             int width_px,
             int height_px,
             double timeout_s,
             std::string* why)
  {
    const std::string exe = findExecutable(executable);
    if (exe.empty()) {
      *why = "'" + executable + "' not found (install the xvfb package)";
      return false;
    }
    int fds[2];
    if (::pipe2(fds, O_CLOEXEC) != 0) {
      *why = std::string("pipe: ") + std::strerror(errno);
      return false;
    }
    constexpr int kChildFd = 3;
    const std::string screen = std::to_string(std::max(width_px, 640)) + "x" +
                               std::to_string(std::max(height_px, 480)) + "x24";
    std::vector<std::string> args = {exe,
                                     "-displayfd",
                                     std::to_string(kChildFd),
                                     "-screen",
                                     "0",
                                     screen,
                                     "-nolisten",
                                     "tcp"};
    std::vector<char*> argv;
    for (auto& a : args)
      argv.push_back(a.data());
    argv.push_back(nullptr);

    const pid_t pid = ::fork();
    if (pid < 0) {
      *why = std::string("fork: ") + std::strerror(errno);
      ::close(fds[0]);
      ::close(fds[1]);
      return false;
    }
    if (pid == 0) {
      // Child: async-signal-safe calls only, then exec.
      ::prctl(PR_SET_PDEATHSIG, SIGKILL); // never outlive the tool
      const int devnull = ::open("/dev/null", O_RDWR);
      if (devnull >= 0) {
        ::dup2(devnull, 0);
        ::dup2(devnull, 1);
        ::dup2(devnull, 2);
      }
      if (fds[1] == kChildFd)
        ::fcntl(kChildFd, F_SETFD, 0);
      else
        ::dup2(fds[1], kChildFd);
      ::execv(exe.c_str(), argv.data());
      ::_exit(127);
    }
    pid_ = pid;
    ::close(fds[1]);

    // The display number arrives as "N\n" once the server accepts clients.
    bool eof = false;
    const std::string text = readLine(fds[0], timeout_s, eof);
    ::close(fds[0]);
    if (text.find('\n') == std::string::npos) {
      if (eof) {
        const int status = reapChild(pid_, 1.0);
        pid_ = -1;
        *why = "Xvfb exited (" + describeStatus(status) + ") before reporting a display";
      } else {
        *why =
            "Xvfb did not report a display within " + formatNumber(timeout_s, 1) + " s";
        stop();
      }
      return false;
    }
    display_ = ":" + text.substr(0, text.find('\n'));
    return true;
  }

  void stop()
  {
    if (pid_ <= 0)
      return;
    ::kill(pid_, SIGTERM);
    reapChild(pid_, 3.0);
    pid_ = -1;
  }

  const std::string& display() const { return display_; }

  pid_t pid() const { return pid_; }

private:
  pid_t pid_ = -1;
  std::string display_;
};


} // namespace render_detail

using namespace render_detail;

bool
MapRenderParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& text) {
    if (why)
      *why = text;
    return false;
  };
  if (width_px < 64 || width_px > 16384)
    return fail("width_px must be in [64, 16384], got " + std::to_string(width_px));
  if (height_px < 64 || height_px > 16384)
    return fail("height_px must be in [64, 16384], got " + std::to_string(height_px));
  if (!(point_size_px >= 1.0f && point_size_px <= 64.0f))
    return fail("point_size_px must be in [1, 64], got " + std::to_string(point_size_px));
  if (!(colour_low_percentile >= 0.0 && colour_low_percentile < colour_high_percentile &&
        colour_high_percentile <= 100.0))
    return fail("colour percentiles must satisfy 0 <= low < high <= 100, got " +
                std::to_string(colour_low_percentile) + ", " +
                std::to_string(colour_high_percentile));
  for (const auto& [name, w] :
       {std::pair<const char*, float>{"trajectory_width_px", trajectory_width_px},
        {"ground_truth_width_px", ground_truth_width_px},
        {"loop_edge_width_px", loop_edge_width_px},
        {"marker_size_px", marker_size_px}})
    if (!(w >= 1.0f && w <= 64.0f))
      return fail(std::string(name) + " must be in [1, 64], got " + std::to_string(w));
  if (!(xvfb_startup_timeout_s > 0.0) || !std::isfinite(xvfb_startup_timeout_s))
    return fail("xvfb_startup_timeout_s must be > 0, got " +
                std::to_string(xvfb_startup_timeout_s));
  if (!(vtk_render_timeout_s > 0.0) || !std::isfinite(vtk_render_timeout_s))
    return fail("vtk_render_timeout_s must be > 0, got " +
                std::to_string(vtk_render_timeout_s));
  if (allow_private_xvfb && xvfb_executable.empty())
    return fail("xvfb_executable must not be empty when allow_private_xvfb is set");
  if (force_software_fallback && !allow_software_fallback)
    return fail("force_software_fallback needs allow_software_fallback");
  return true;
}

MapRenderResult
renderMapTopDown(const MapRenderInput& input,
                 const MapRenderParams& params,
                 const std::string& png_path)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("renderMapTopDown: invalid MapRenderParams: " + why);
  if (!input.map)
    throw std::invalid_argument("renderMapTopDown: input.map is null");
  if (png_path.empty())
    throw std::invalid_argument("renderMapTopDown: png_path is empty");

  const pcl::StopWatch watch;
  MapRenderResult result;
  auto finish = [&](MapRenderResult& r) -> MapRenderResult {
    r.render_time_ms = 1000.0 * watch.getTimeSeconds();
    return r;
  };
  try {
    const Scene scene = prepareScene(input, params);
    result.map_points_drawn = scene.points.size();
    cv::Mat image;
    std::vector<std::string> failures;

    if (params.force_software_fallback)
      failures.push_back("VTK skipped (force_software_fallback)");
    else {
      // 1. The user's display, if any.
      const char* env_display = std::getenv("DISPLAY");
      if (env_display && *env_display) {
        std::string reason;
        if (renderSceneVtkIsolated(scene, params, env_display, &image, &reason))
          result.backend = "vtk-x";
        else
          failures.push_back("DISPLAY '" + std::string(env_display) + "': " + reason);
      } else
        failures.push_back("DISPLAY not set");
      // 2. A private Xvfb, stopped before we leave this block, whatever happens.
      if (result.backend.empty() && params.allow_private_xvfb) {
        PrivateXServer xvfb;
        std::string reason;
        if (xvfb.start(params.xvfb_executable,
                       params.width_px,
                       params.height_px,
                       params.xvfb_startup_timeout_s,
                       &reason)) {
          result.xvfb_pid = xvfb.pid();
          if (renderSceneVtkIsolated(scene, params, xvfb.display(), &image, &reason))
            result.backend = "vtk-xvfb";
          else
            failures.push_back("Xvfb " + xvfb.display() + ": " + reason);
        } else
          failures.push_back("Xvfb: " + reason);
        xvfb.stop();
      }
    }

    std::string failure_text;
    for (const auto& f : failures)
      failure_text += (failure_text.empty() ? "" : "; ") + f;
    if (result.backend.empty()) {
      if (!params.allow_software_fallback) {
        result.message = "VTK could not render: " + failure_text;
        return finish(result);
      }
      image = rasterizeScene(scene, params);
      result.backend = "opencv-fallback";
      result.message = "software rasterization: " + failure_text;
    } else if (result.backend == "vtk-xvfb")
      result.message = "private Xvfb used: " + failure_text;
    drawOverlays(image, scene, params, input.title, result.backend);

    std::string write_error;
    if (!writePngAtomically(image, png_path, &write_error)) {
      result.message =
          write_error + (result.message.empty() ? "" : " (" + result.message + ")");
      return finish(result);
    }
    result.success = true;
  } catch (const std::exception& e) {
    result.success = false;
    result.message = std::string("rendering failed: ") + e.what();
  }
  return finish(result);
}


} // namespace rast
} // namespace pcl
