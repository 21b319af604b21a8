/// \file render_vtk.cpp
/// \brief The scene rendered offscreen by VTK, in a forked child process.

#include "render_scene.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
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
#include <vtkActor.h>
#include <vtkAutoInit.h>
#include <vtkCallbackCommand.h>
#include <vtkCamera.h>
#include <vtkCellArray.h>
#include <vtkCommand.h>
#include <vtkImageData.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkProperty.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkSmartPointer.h>
#include <vtkUnsignedCharArray.h>
#include <vtkWindowToImageFilter.h>

// Xlib last: it defines macros (None, Status, Bool, ...) that clash with other headers.
#include <X11/Xlib.h>

VTK_MODULE_INIT(vtkRenderingOpenGL2);

namespace pcl {
namespace rast {
namespace render_detail {

vtkSmartPointer<vtkActor>
makeActor(vtkPolyData* data, const RgbColour& colour, float width_px, bool direct_colours)
{
  auto mapper = vtkSmartPointer<vtkPolyDataMapper>::New();
  mapper->SetInputData(data);
  if (direct_colours) {
    mapper->SetColorModeToDirectScalars();
    mapper->SetScalarModeToUsePointData();
    mapper->ScalarVisibilityOn();
  } else
    mapper->ScalarVisibilityOff();
  auto actor = vtkSmartPointer<vtkActor>::New();
  actor->SetMapper(mapper);
  vtkProperty* prop = actor->GetProperty();
  prop->LightingOff(); // exact colours, as in the legend
  prop->SetColor(colour.r / 255.0, colour.g / 255.0, colour.b / 255.0);
  prop->SetPointSize(width_px);
  prop->SetLineWidth(width_px);
  return actor;
}

/// Polyline(s) at height \a z_m; \a segments: consecutive pairs, else one polyline.
vtkSmartPointer<vtkPolyData>
makeLines(const std::vector<Eigen::Vector3d>& pts, double z_m, bool segments, bool closed)
{
  auto points = vtkSmartPointer<vtkPoints>::New();
  auto lines = vtkSmartPointer<vtkCellArray>::New();
  for (const auto& p : pts)
    points->InsertNextPoint(p.x(), p.y(), z_m);
  if (segments) {
    for (vtkIdType i = 0; i + 1 < static_cast<vtkIdType>(pts.size()); i += 2) {
      const vtkIdType ids[2] = {i, i + 1};
      lines->InsertNextCell(2, ids);
    }
  } else if (pts.size() >= 2) {
    lines->InsertNextCell(static_cast<vtkIdType>(pts.size() + (closed ? 1 : 0)));
    for (vtkIdType i = 0; i < static_cast<vtkIdType>(pts.size()); ++i)
      lines->InsertCellPoint(i);
    if (closed)
      lines->InsertCellPoint(0);
  }
  auto data = vtkSmartPointer<vtkPolyData>::New();
  data->SetPoints(points);
  data->SetLines(lines);
  return data;
}

void
addMarker(vtkRenderer* renderer,
          const Eigen::Vector3d& centre,
          double radius_m,
          bool square,
          const RgbColour& fill,
          double z_m,
          float outline_px)
{
  std::vector<Eigen::Vector3d> ring;
  for (const auto& q : markerPolygon(centre, radius_m, square))
    ring.emplace_back(q.x(), q.y(), 0.0);
  auto polygon = makeLines(ring, z_m, false, false);
  auto polys = vtkSmartPointer<vtkCellArray>::New();
  polys->InsertNextCell(static_cast<vtkIdType>(ring.size()));
  for (vtkIdType i = 0; i < static_cast<vtkIdType>(ring.size()); ++i)
    polys->InsertCellPoint(i);
  auto disc = vtkSmartPointer<vtkPolyData>::New();
  disc->SetPoints(polygon->GetPoints());
  disc->SetPolys(polys);
  renderer->AddActor(makeActor(disc, fill, 1.0f, false));
  renderer->AddActor(makeActor(
      makeLines(ring, z_m + 0.5, false, true), kMarkerOutline, outline_px, false));
}

/// Render the scene (points, lines, markers; no overlays) with VTK offscreen on the X
/// display \a display. Fills \a bgr. Runs in the forked child.
namespace {

/// Map points: one poly-vertex cell, direct RGB colours.
void
addMapPoints(vtkRenderer* renderer, const Scene& s, const MapRenderParams& params)
{
  if (s.points.empty())
    return;
  auto points = vtkSmartPointer<vtkPoints>::New();
  points->SetDataTypeToFloat();
  points->SetNumberOfPoints(static_cast<vtkIdType>(s.points.size()));
  auto colours = vtkSmartPointer<vtkUnsignedCharArray>::New();
  colours->SetNumberOfComponents(3);
  colours->SetNumberOfTuples(static_cast<vtkIdType>(s.points.size()));
  auto verts = vtkSmartPointer<vtkCellArray>::New();
  verts->InsertNextCell(static_cast<vtkIdType>(s.points.size()));
  for (std::size_t i = 0; i < s.points.size(); ++i) {
    const auto id = static_cast<vtkIdType>(i);
    points->SetPoint(id, s.points[i].x(), s.points[i].y(), s.points[i].z());
    const cv::Vec3b& c = s.point_bgr[i];
    const unsigned char rgb[3] = {c[2], c[1], c[0]};
    colours->SetTypedTuple(id, rgb);
    verts->InsertCellPoint(id);
  }
  auto cloud = vtkSmartPointer<vtkPolyData>::New();
  cloud->SetPoints(points);
  cloud->SetVerts(verts);
  cloud->GetPointData()->SetScalars(colours);
  renderer->AddActor(makeActor(cloud, RgbColour{}, params.point_size_px, true));
}

/// Lines and markers float above the map, in drawing order.
void
addLinesAndMarkers(vtkRenderer* renderer, const Scene& s, const MapRenderParams& params)
{
  const TopDownView& v = s.view;
  const double z = s.z_top_m;
  if (s.ground_truth.size() >= 2)
    renderer->AddActor(makeActor(makeLines(s.ground_truth, z + 1.0, false, false),
                                 params.ground_truth_colour,
                                 params.ground_truth_width_px,
                                 false));
  if (s.trajectory.size() >= 2)
    renderer->AddActor(makeActor(makeLines(s.trajectory, z + 2.0, false, false),
                                 params.trajectory_colour,
                                 params.trajectory_width_px,
                                 false));
  if (!s.loop_edges.empty()) {
    std::vector<Eigen::Vector3d> ends;
    for (const auto& e : s.loop_edges)
      ends.push_back(e.first), ends.push_back(e.second);
    renderer->AddActor(makeActor(makeLines(ends, z + 3.0, true, false),
                                 params.loop_edge_colour,
                                 params.loop_edge_width_px,
                                 false));
  }
  if (params.draw_start_end_markers && !s.trajectory.empty()) {
    const double r_m = params.marker_size_px * v.m_per_px;
    const auto outline = static_cast<float>(std::max(1.0, 2.0 * s.layout.scale));
    addMarker(renderer, s.trajectory.back(), r_m, true, kEndColour, z + 4.0, outline);
    addMarker(renderer, s.trajectory.front(), r_m, false, kStartColour, z + 6.0, outline);
  }
}

/// Orthographic camera looking down -z, north (+y) up, fitted by prepareScene().
void
setTopDownCamera(vtkRenderer* renderer, const Scene& s)
{
  const TopDownView& v = s.view;
  const double z = s.z_top_m;
  vtkCamera* camera = renderer->GetActiveCamera();
  const double cam_z = z + 20.0;
  camera->ParallelProjectionOn();
  camera->SetFocalPoint(v.cam_x_m, v.cam_y_m, s.z_min_m);
  camera->SetPosition(v.cam_x_m, v.cam_y_m, cam_z);
  camera->SetViewUp(0.0, 1.0, 0.0);
  camera->SetParallelScale(0.5 * v.height_px * v.m_per_px);
  camera->SetClippingRange(0.1, cam_z - s.z_min_m + 1.0);
}

/// The rendered image of \a window as BGR rows top-down in \a bgr; false (and why)
/// on a VTK error or an image of the wrong size.
bool
grabImage(vtkRenderWindow* window,
          const TopDownView& v,
          const std::string& vtk_errors,
          cv::Mat* bgr,
          std::string* why)
{
  auto grab = vtkSmartPointer<vtkWindowToImageFilter>::New();
  grab->SetInput(window);
  grab->SetInputBufferTypeToRGB();
  grab->ReadFrontBufferOff();
  grab->Update();
  vtkImageData* image = grab->GetOutput();
  int dims[3] = {0, 0, 0};
  image->GetDimensions(dims);
  auto* scalars = image->GetPointData() ? image->GetPointData()->GetScalars() : nullptr;
  if (!vtk_errors.empty()) {
    *why = "VTK: " + vtk_errors;
    return false;
  }
  if (dims[0] != v.width_px || dims[1] != v.height_px || !scalars ||
      scalars->GetNumberOfComponents() != 3) {
    *why = "VTK returned a " + std::to_string(dims[0]) + " x " + std::to_string(dims[1]) +
           " image instead of " + std::to_string(v.width_px) + " x " +
           std::to_string(v.height_px);
    return false;
  }
  // VTK rows run bottom-up, RGB; OpenCV top-down, BGR.
  const auto* rgb = static_cast<const unsigned char*>(image->GetScalarPointer());
  *bgr = cv::Mat(v.height_px, v.width_px, CV_8UC3);
  for (int row = 0; row < v.height_px; ++row) {
    const unsigned char* src = rgb + 3 * static_cast<std::size_t>(v.width_px) *
                                         static_cast<std::size_t>(v.height_px - 1 - row);
    auto* dst = bgr->ptr<cv::Vec3b>(row);
    for (int col = 0; col < v.width_px; ++col)
      dst[col] = cv::Vec3b(src[3 * col + 2], src[3 * col + 1], src[3 * col]);
  }
  return true;
}

} // namespace

bool
renderSceneVtk(const Scene& s,
               const MapRenderParams& params,
               const std::string& display,
               cv::Mat* bgr,
               std::string* why)
{
  ::setenv("DISPLAY", display.c_str(), 1); // the child is single-threaded
  Display* x_display = XOpenDisplay(display.c_str());
  if (!x_display) {
    *why = "cannot open X display '" + display + "'";
    return false;
  }
  int opcode = 0, event = 0, error = 0;
  if (!XQueryExtension(x_display, "GLX", &opcode, &event, &error)) {
    XCloseDisplay(x_display);
    *why = "X display '" + display + "' has no GLX extension";
    return false;
  }

  bool ok = true;
  {
    std::string vtk_errors;
    auto on_error = vtkSmartPointer<vtkCallbackCommand>::New();
    on_error->SetClientData(&vtk_errors);
    on_error->SetCallback([](vtkObject*, unsigned long, void* client, void* call) {
      auto* text = static_cast<std::string*>(client);
      *text += call ? static_cast<const char*>(call) : "VTK error";
      *text += "; ";
    });

    const TopDownView& v = s.view;
    auto window = vtkSmartPointer<vtkRenderWindow>::New();
    window->AddObserver(vtkCommand::ErrorEvent, on_error);
    window->SetDisplayId(x_display);
    window->SetOffScreenRendering(1);
    window->SetMultiSamples(8); // smooth lines; line centres keep their exact colour
    window->SetSize(v.width_px, v.height_px);
    auto renderer = vtkSmartPointer<vtkRenderer>::New();
    renderer->AddObserver(vtkCommand::ErrorEvent, on_error);
    renderer->SetBackground(params.background.r / 255.0,
                            params.background.g / 255.0,
                            params.background.b / 255.0);
    window->AddRenderer(renderer);

    addMapPoints(renderer, s, params);
    addLinesAndMarkers(renderer, s, params);
    setTopDownCamera(renderer, s);
    window->Render();
    ok = grabImage(window, v, vtk_errors, bgr, why);
    window->Finalize();
  }
  XCloseDisplay(x_display);
  return ok;
}

bool
writeAll(int fd, const void* data, std::size_t size)
{
  const auto* p = static_cast<const char*>(data);
  while (size > 0) {
    const ssize_t n = ::write(fd, p, size);
    if (n < 0 && errno == EINTR)
      continue;
    if (n <= 0)
      return false;
    p += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

namespace {

/// The forked child: render, send [ok][n][message][pixels] on \a data_fd, exit.
[[noreturn]] void
renderInChild(const Scene& s,
              const MapRenderParams& params,
              const std::string& display,
              int data_fd,
              int err_fd)
{
  ::prctl(PR_SET_PDEATHSIG, SIGKILL);
  ::dup2(err_fd, 2); // VTK, Mesa and Xlib complain on stderr
  std::int32_t ok = 0;
  std::string message;
  cv::Mat image;
  try {
    ok = renderSceneVtk(s, params, display, &image, &message) ? 1 : 0;
  } catch (const std::exception& e) {
    message = e.what();
  } catch (...) {
    message = "unknown exception";
  }
  message = message.substr(0, 4000);
  const auto n = static_cast<std::int32_t>(message.size());
  bool sent = writeAll(data_fd, &ok, sizeof(ok)) && writeAll(data_fd, &n, sizeof(n)) &&
              writeAll(data_fd, message.data(), message.size());
  if (sent && ok)
    sent = writeAll(data_fd, image.data, image.total() * image.elemSize());
  ::_exit(sent ? 0 : 1); // no atexit handlers, no flushing of the parent's buffers
}

/// Read both pipes until the data pipe closes or \a timeout_s passes (then true).
bool
readChildOutput(
    int data_fd, int err_fd, double timeout_s, std::string& data, std::string& errors)
{
  const pcl::StopWatch watch;
  bool data_open = true, err_open = true, timed_out = false;
  while (data_open) {
    const double left_s = timeout_s - watch.getTimeSeconds();
    if (left_s <= 0.0) {
      timed_out = true;
      break;
    }
    pollfd pfds[2] = {{data_fd, POLLIN, 0}, {err_open ? err_fd : -1, POLLIN, 0}};
    const int r =
        ::poll(pfds, 2, static_cast<int>(std::min(1000.0, std::ceil(left_s * 1000.0))));
    if (r < 0 && errno != EINTR)
      break;
    char buf[1 << 16];
    if (pfds[0].revents) {
      const ssize_t n = ::read(data_fd, buf, sizeof(buf));
      if (n > 0)
        data.append(buf, static_cast<std::size_t>(n));
      else if (n == 0 || errno != EINTR)
        data_open = false;
    }
    if (err_open && pfds[1].revents) {
      const ssize_t n = ::read(err_fd, buf, sizeof(buf));
      if (n > 0) {
        errors.append(buf, static_cast<std::size_t>(n));
        if (errors.size() > 8192)
          errors.erase(0, errors.size() - 8192);
      } else if (n == 0 || errno != EINTR)
        err_open = false;
    }
  }
  return timed_out;
}

/// A short excerpt of what the child printed, for the message.
std::string
stderrTail(const std::string& errors)
{
  std::string t;
  for (std::size_t i = 0; i < errors.size(); ++i) { // drop ANSI colour codes
    if (errors[i] == '\x1b' && i + 1 < errors.size() && errors[i + 1] == '[') {
      i += 2;
      while (i < errors.size() && !std::isalpha(static_cast<unsigned char>(errors[i])))
        ++i;
    } else
      t += errors[i];
  }
  while (!t.empty() && std::isspace(static_cast<unsigned char>(t.back())))
    t.pop_back();
  if (t.size() > 400)
    t = "..." + t.substr(t.size() - 400);
  for (char& c : t)
    if (c == '\n')
      c = ' ';
  return t.empty() ? std::string() : " [stderr: " + t + "]";
}

/// The child's reply: the image in \a bgr, or why not.
bool
decodeReply(const std::string& data,
            const std::string& errors,
            int status,
            const Scene& s,
            cv::Mat* bgr,
            std::string* why)
{
  std::int32_t ok = 0, n = 0;
  if (data.size() < 2 * sizeof(std::int32_t)) {
    *why =
        "VTK render process died (" + describeStatus(status) + ")" + stderrTail(errors);
    return false;
  }
  std::memcpy(&ok, data.data(), sizeof(ok));
  std::memcpy(&n, data.data() + sizeof(ok), sizeof(n));
  const std::size_t header = 2 * sizeof(std::int32_t);
  if (n < 0 || data.size() < header + static_cast<std::size_t>(n)) {
    *why = "VTK render process sent a truncated reply (" + describeStatus(status) + ")";
    return false;
  }
  const std::string message = data.substr(header, static_cast<std::size_t>(n));
  if (!ok) {
    *why = message + stderrTail(errors);
    return false;
  }
  const std::size_t pixels =
      3 * static_cast<std::size_t>(s.view.width_px) * s.view.height_px;
  if (data.size() != header + n + pixels) {
    *why = "VTK render process sent " + std::to_string(data.size() - header - n) +
           " pixel bytes instead of " + std::to_string(pixels);
    return false;
  }
  cv::Mat(s.view.height_px,
          s.view.width_px,
          CV_8UC3,
          const_cast<char*>(data.data() + header + n))
      .copyTo(*bgr);
  return true;
}

} // namespace

/// Run renderSceneVtk() in a forked child, so that an abort(), exit() or crash inside
/// VTK, Mesa or Xlib (they do all three on a broken display) only fails this call.
/// The child sends [int32 ok][int32 n][n bytes message][W*H*3 BGR pixels if ok].
bool
renderSceneVtkIsolated(const Scene& s,
                       const MapRenderParams& params,
                       const std::string& display,
                       cv::Mat* bgr,
                       std::string* why)
{
  int data_pipe[2], err_pipe[2];
  if (::pipe2(data_pipe, O_CLOEXEC) != 0) {
    *why = std::string("pipe: ") + std::strerror(errno);
    return false;
  }
  if (::pipe2(err_pipe, O_CLOEXEC) != 0) {
    *why = std::string("pipe: ") + std::strerror(errno);
    ::close(data_pipe[0]);
    ::close(data_pipe[1]);
    return false;
  }
  std::fflush(nullptr);
  const pid_t pid = ::fork();
  if (pid < 0) {
    *why = std::string("fork: ") + std::strerror(errno);
    for (int fd : {data_pipe[0], data_pipe[1], err_pipe[0], err_pipe[1]})
      ::close(fd);
    return false;
  }
  if (pid == 0) {
    ::close(data_pipe[0]);
    ::close(err_pipe[0]);
    renderInChild(s, params, display, data_pipe[1], err_pipe[1]);
  }
  ::close(data_pipe[1]);
  ::close(err_pipe[1]);
  std::string data, errors;
  const bool timed_out = readChildOutput(
      data_pipe[0], err_pipe[0], params.vtk_render_timeout_s, data, errors);
  ::close(data_pipe[0]);
  ::close(err_pipe[0]);
  if (timed_out)
    ::kill(pid, SIGKILL);
  const int status = reapChild(pid, 5.0);
  if (timed_out) {
    *why = "VTK render did not finish within " +
           formatNumber(params.vtk_render_timeout_s, 0) + " s" + stderrTail(errors);
    return false;
  }
  return decodeReply(data, errors, status, s, bgr, why);
}

} // namespace render_detail
} // namespace rast
} // namespace pcl
