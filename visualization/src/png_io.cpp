/// \file png_io.cpp
/// \brief savePng and loadPng with VTK's PNG writer and reader. The writer encodes into
/// memory and writeFileAtomically puts the bytes on disk, so a full disk or a missing
/// folder is reported, and never leaves a part of a picture behind.

#include <cstring>
#include <filesystem>
#include <pcl/rast/atomic_file.h>
#include <pcl/visualization/png_io.h>
#include <stdexcept>
#include <utility>
#include <vtkCommand.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPNGReader.h>
#include <vtkPNGWriter.h>
#include <vtkSmartPointer.h>
#include <vtkUnsignedCharArray.h>

namespace pcl {
namespace rast {
namespace {

/// Takes the messages VTK would print for an algorithm (vtkErrorMacro sends them to an
/// ErrorEvent observer instead of the output window), so the exception can carry them.
class ErrorCollector : public vtkCommand
{
public:
  static ErrorCollector* New() { return new ErrorCollector; }
  void Execute(vtkObject*, unsigned long, void* call_data) override
  {
    if (call_data && message.empty())
      message = static_cast<const char*>(call_data);
  }
  std::string message;
};

/// Swap the first and third channel of every pixel (BGR <-> RGB) when there are three
/// or four channels.
void
swapRedAndBlue(std::uint8_t* row, int width, int channels)
{
  if (channels < 3)
    return;
  for (int x = 0; x < width; ++x)
    std::swap(row[x * channels], row[x * channels + 2]);
}

} // namespace

void
savePng(const std::string& path, const Image8& image)
{
  if (image.width <= 0 || image.height <= 0)
    throw std::invalid_argument("savePng: bad image size " + std::to_string(image.width) +
                                " x " + std::to_string(image.height) + " for '" + path +
                                "'");
  if (image.channels < 1 || image.channels > 4)
    throw std::invalid_argument("savePng: bad channel count " +
                                std::to_string(image.channels) + " for '" + path +
                                "' (1 to 4)");
  const std::size_t row_bytes = static_cast<std::size_t>(image.width) * image.channels;
  if (image.pixels.size() != row_bytes * image.height)
    throw std::invalid_argument(
        "savePng: " + std::to_string(image.pixels.size()) + " pixel bytes for a " +
        std::to_string(image.width) + " x " + std::to_string(image.height) + " x " +
        std::to_string(image.channels) + " image ('" + path + "')");

  // VTK's image rows run from the bottom up, and its colours are RGB.
  vtkNew<vtkImageData> data;
  data->SetDimensions(image.width, image.height, 1);
  data->AllocateScalars(VTK_UNSIGNED_CHAR, image.channels);
  for (int r = 0; r < image.height; ++r) {
    auto* dst =
        static_cast<std::uint8_t*>(data->GetScalarPointer(0, image.height - 1 - r, 0));
    std::memcpy(dst, image.pixels.data() + r * row_bytes, row_bytes);
    swapRedAndBlue(dst, image.width, image.channels);
  }

  vtkNew<vtkPNGWriter> writer;
  vtkNew<ErrorCollector> errors;
  writer->AddObserver(vtkCommand::ErrorEvent, errors);
  writer->SetInputData(data);
  writer->WriteToMemoryOn();
  writer->Write();
  vtkUnsignedCharArray* bytes = writer->GetResult();
  if (!errors->message.empty() || !bytes || bytes->GetNumberOfValues() == 0)
    throw std::runtime_error("cannot encode '" + path + "' as PNG" +
                             (errors->message.empty() ? "" : ": " + errors->message));
  try {
    writeFileAtomically(
        path,
        std::string(reinterpret_cast<const char*>(bytes->GetPointer(0)),
                    static_cast<std::size_t>(bytes->GetNumberOfValues())));
  } catch (const std::runtime_error& e) {
    throw std::runtime_error("cannot write '" + path + "': " + e.what());
  }
}

Image8
loadPng(const std::string& path)
{
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    throw std::runtime_error("cannot read '" + path + "': no such file");
  vtkNew<vtkPNGReader> reader;
  vtkNew<ErrorCollector> errors;
  reader->AddObserver(vtkCommand::ErrorEvent, errors);
  if (!reader->CanReadFile(path.c_str()))
    throw std::runtime_error("cannot read '" + path + "': not a PNG file");
  reader->SetFileName(path.c_str());
  reader->Update();
  vtkImageData* data = reader->GetOutput();
  if (!errors->message.empty() || !data || data->GetNumberOfPoints() == 0)
    throw std::runtime_error("cannot read '" + path + "'" +
                             (errors->message.empty() ? "" : ": " + errors->message));
  if (data->GetScalarType() != VTK_UNSIGNED_CHAR)
    throw std::runtime_error("cannot read '" + path + "': not an 8-bit PNG (" +
                             data->GetScalarTypeAsString() + " samples)");
  int dims[3];
  data->GetDimensions(dims);
  Image8 image;
  image.width = dims[0];
  image.height = dims[1];
  image.channels = data->GetNumberOfScalarComponents();
  const std::size_t row_bytes = static_cast<std::size_t>(image.width) * image.channels;
  image.pixels.resize(row_bytes * image.height);
  for (int r = 0; r < image.height; ++r) {
    std::uint8_t* dst = image.pixels.data() + r * row_bytes;
    std::memcpy(dst, data->GetScalarPointer(0, image.height - 1 - r, 0), row_bytes);
    swapRedAndBlue(dst, image.width, image.channels);
  }
  return image;
}

} // namespace rast
} // namespace pcl
