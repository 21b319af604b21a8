/// \file scan_parsing.cpp
/// \brief PCD and PLY parsed without trusting the header (scan_parsing.h). The header is
/// read line by line with bounded lengths, every declared size is checked against the
/// file before any allocation, and ascii values must be numbers of the declared type.

#include "scan_parsing.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>
#include <pcl/common/io.h> // getFieldSize
#include <pcl/io/lzf.h>
#include <pcl/io/sequence_reader.h> // ScanReadError
#include <string_view>
#include <vector>

namespace pcl {
namespace rast {
namespace io_detail {

namespace {

constexpr std::size_t kMaxHeaderLineBytes = 64 * 1024;
constexpr std::size_t kMaxHeaderBytes = 1024 * 1024;
constexpr std::size_t kMaxFields = 4096;
constexpr std::uint64_t kMaxPointStep = 1024 * 1024;
/// LZF expands at most ~88x (a 3-byte back reference copies 264 bytes); a declared
/// uncompressed size above this ratio cannot be genuine.
constexpr std::uint64_t kMaxLzfRatio = 100;

/// The text lines of a header, read from \a bytes with bounded lengths.
class HeaderLines
{
public:
  HeaderLines(const std::string& path, std::string_view bytes, const char* format)
      : path_(path), bytes_(bytes), format_(format)
  {}

  /// The next line without its line ending; false at the end of the file.
  bool next(std::string_view& line)
  {
    if (pos_ >= bytes_.size())
      return false;
    const std::size_t end = bytes_.find('\n', pos_);
    const std::size_t stop = end == std::string_view::npos ? bytes_.size() : end;
    if (stop - pos_ > kMaxHeaderLineBytes)
      fail("header line " + std::to_string(line_number_ + 1) + " is longer than " +
           std::to_string(kMaxHeaderLineBytes) + " bytes");
    line = bytes_.substr(pos_, stop - pos_);
    if (!line.empty() && line.back() == '\r')
      line.remove_suffix(1);
    pos_ = end == std::string_view::npos ? bytes_.size() : end + 1;
    ++line_number_;
    if (pos_ > kMaxHeaderBytes)
      fail("header is longer than " + std::to_string(kMaxHeaderBytes) + " bytes");
    return true;
  }

  /// Offset of the first byte after the lines read so far.
  std::size_t offset() const { return pos_; }
  std::size_t lineNumber() const { return line_number_; }

  [[noreturn]] void fail(const std::string& why) const
  {
    throw ScanReadError(path_, std::string("cannot parse ") + format_ + " file: " + why);
  }

private:
  const std::string& path_;
  std::string_view bytes_;
  const char* format_;
  std::size_t pos_ = 0;
  std::size_t line_number_ = 0;
};

std::vector<std::string_view>
splitWords(std::string_view line)
{
  std::vector<std::string_view> words;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t'))
      ++i;
    const std::size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t')
      ++i;
    if (i > start)
      words.push_back(line.substr(start, i - start));
  }
  return words;
}

/// A header count: decimal digits only, no sign, at most \a max.
bool
parseCount(std::string_view word, std::uint64_t max, std::uint64_t& value)
{
  if (word.empty() || word.front() < '0' || word.front() > '9')
    return false;
  const auto [end, ec] = std::from_chars(word.data(), word.data() + word.size(), value);
  return ec == std::errc() && end == word.data() + word.size() && value <= max;
}

/// The PCLPointField datatype of a value of \a size bytes that is a float (\a kind 'F'),
/// signed ('I') or unsigned ('U') integer; 0 for an impossible combination.
std::uint8_t
datatypeOf(char kind, std::uint64_t size)
{
  using F = pcl::PCLPointField;
  switch (kind) {
  case 'F':
    return size == 4 ? F::FLOAT32 : size == 8 ? F::FLOAT64 : 0;
  case 'I':
    return size == 1   ? F::INT8
           : size == 2 ? F::INT16
           : size == 4 ? F::INT32
           : size == 8 ? F::INT64
                       : 0;
  case 'U':
    return size == 1   ? F::UINT8
           : size == 2 ? F::UINT16
           : size == 4 ? F::UINT32
           : size == 8 ? F::UINT64
                       : 0;
  default:
    return 0;
  }
}

template <typename T>
bool
storeInteger(std::string_view word, std::uint8_t* out)
{
  T value{};
  const auto [end, ec] = std::from_chars(word.data(), word.data() + word.size(), value);
  if (ec != std::errc() || end != word.data() + word.size())
    return false;
  std::memcpy(out, &value, sizeof value);
  return true;
}

/// Store the ascii number \a word as a value of \a datatype at \a out; false when it is
/// not a number of that type (a word, a fraction for an integer, out of range).
bool
storeValue(std::string_view word, std::uint8_t datatype, std::uint8_t* out)
{
  using F = pcl::PCLPointField;
  switch (datatype) {
  case F::INT8:
    return storeInteger<std::int8_t>(word, out);
  case F::UINT8:
    return storeInteger<std::uint8_t>(word, out);
  case F::INT16:
    return storeInteger<std::int16_t>(word, out);
  case F::UINT16:
    return storeInteger<std::uint16_t>(word, out);
  case F::INT32:
    return storeInteger<std::int32_t>(word, out);
  case F::UINT32:
    return storeInteger<std::uint32_t>(word, out);
  case F::INT64:
    return storeInteger<std::int64_t>(word, out);
  case F::UINT64:
    return storeInteger<std::uint64_t>(word, out);
  default:
    break;
  }
  // from_chars takes no leading '+', which writers do emit.
  if (!word.empty() && word.front() == '+')
    word.remove_prefix(1);
  double value = 0.0;
  const auto [end, ec] = std::from_chars(word.data(), word.data() + word.size(), value);
  // Out of range (1e999) is kept as inf and dropped later as a non-finite point.
  if ((ec != std::errc() && ec != std::errc::result_out_of_range) ||
      end != word.data() + word.size())
    return false;
  if (datatype == F::FLOAT32) {
    const float f = static_cast<float>(value);
    std::memcpy(out, &f, sizeof f);
  } else {
    std::memcpy(out, &value, sizeof value);
  }
  return true;
}

/// One value slot of a point: where it goes and what it is.
struct Slot
{
  std::uint32_t offset;
  std::uint8_t datatype;
};

/// The slots of one point in field order, every element of a multi-count field apart.
std::vector<Slot>
slotsOf(const pcl::PCLPointCloud2& blob)
{
  std::vector<Slot> slots;
  for (const pcl::PCLPointField& f : blob.fields)
    for (std::uint32_t k = 0; k < f.count; ++k)
      slots.push_back({f.offset + k * pcl::getFieldSize(f.datatype), f.datatype});
  return slots;
}

/// Ascii point data, one point per non-empty line after the header, into blob.data
/// (already sized for \a num_points).
void
parseAsciiPoints(HeaderLines& lines, pcl::PCLPointCloud2& blob, std::uint64_t num_points)
{
  const std::vector<Slot> slots = slotsOf(blob);
  std::uint64_t done = 0;
  std::string_view line;
  while (done < num_points && lines.next(line)) {
    const std::vector<std::string_view> words = splitWords(line);
    if (words.empty())
      continue;
    if (words.size() != slots.size())
      lines.fail("line " + std::to_string(lines.lineNumber()) + " has " +
                 std::to_string(words.size()) + " values, expected " +
                 std::to_string(slots.size()));
    std::uint8_t* point = blob.data.data() + done * blob.point_step;
    for (std::size_t k = 0; k < slots.size(); ++k)
      if (!storeValue(words[k], slots[k].datatype, point + slots[k].offset))
        lines.fail("line " + std::to_string(lines.lineNumber()) + ": '" +
                   std::string(words[k].substr(0, 40)) +
                   "' is not a number of the declared type");
    ++done;
  }
  if (done < num_points)
    lines.fail("ascii data holds " + std::to_string(done) + " of the " +
               std::to_string(num_points) + " points the header declares");
}

/// Fail unless \a num_points of blob.point_step bytes stay within the limits and
/// \a available bytes can hold them (min_bytes_per_point each).
void
checkPointCount(const HeaderLines& lines,
                const pcl::PCLPointCloud2& blob,
                std::uint64_t num_points,
                std::uint64_t available,
                std::uint64_t min_bytes_per_point)
{
  if (num_points > kMaxScanDataBytes / blob.point_step)
    lines.fail(std::to_string(num_points) + " points of " +
               std::to_string(blob.point_step) + " bytes exceed the limit of " +
               std::to_string(kMaxScanDataBytes) + " bytes");
  if (min_bytes_per_point > 0 && num_points > available / min_bytes_per_point)
    lines.fail("truncated data: the header declares " + std::to_string(num_points) +
               " points but only " + std::to_string(available) + " bytes follow");
}

/// Size blob.data for \a num_points after checking the total against the limits.
void
allocatePoints(const HeaderLines& lines,
               pcl::PCLPointCloud2& blob,
               std::uint64_t num_points,
               std::uint64_t available,
               std::uint64_t min_bytes_per_point)
{
  checkPointCount(lines, blob, num_points, available, min_bytes_per_point);
  blob.data.assign(static_cast<std::size_t>(num_points * blob.point_step), 0);
}

// ---------------------------------------------------------------------------- PCD

struct PcdHeader
{
  std::vector<std::string> names;
  std::vector<std::uint64_t> sizes, counts;
  std::vector<char> types;
  bool has_width = false, has_height = false, has_points = false;
  std::uint64_t width = 0, height = 1, points = 0;
  std::string data;
};

/// Read the header lines up to and including DATA.
PcdHeader
readPcdHeader(HeaderLines& lines)
{
  PcdHeader h;
  std::string_view line;
  while (h.data.empty()) {
    if (!lines.next(line))
      lines.fail("no DATA line: the header never ends");
    const std::vector<std::string_view> words = splitWords(line);
    if (words.empty() || words[0].front() == '#')
      continue;
    const std::string key(words[0]);
    const std::size_t n = words.size() - 1;
    auto values = [&](std::uint64_t max, std::vector<std::uint64_t>& out) {
      if (!out.empty())
        lines.fail(key + " appears twice");
      for (std::size_t k = 1; k < words.size(); ++k) {
        std::uint64_t v = 0;
        if (!parseCount(words[k], max, v))
          lines.fail(key + " value '" + std::string(words[k].substr(0, 40)) +
                     "' is not a whole number from 0 to " + std::to_string(max));
        out.push_back(v);
      }
    };
    auto single = [&](bool& seen, std::uint64_t& out) {
      if (seen || n != 1 ||
          !parseCount(words[1], std::numeric_limits<std::uint32_t>::max(), out))
        lines.fail(key + " needs one whole number from 0 to 4294967295 (line " +
                   std::to_string(lines.lineNumber()) + ")");
      seen = true;
    };
    if (key == "VERSION" || key == "VIEWPOINT") {
      continue;
    } else if (key == "FIELDS" || key == "COLUMNS") {
      if (!h.names.empty() || n == 0 || n > kMaxFields)
        lines.fail("FIELDS must appear once with 1 to " + std::to_string(kMaxFields) +
                   " names");
      for (std::size_t k = 1; k < words.size(); ++k)
        h.names.emplace_back(words[k]);
    } else if (key == "SIZE") {
      values(8, h.sizes);
    } else if (key == "COUNT") {
      values(kMaxPointStep, h.counts);
    } else if (key == "TYPE") {
      if (!h.types.empty())
        lines.fail("TYPE appears twice");
      for (std::size_t k = 1; k < words.size(); ++k)
        h.types.push_back(words[k].size() == 1 ? words[k][0] : '?');
    } else if (key == "WIDTH") {
      single(h.has_width, h.width);
    } else if (key == "HEIGHT") {
      single(h.has_height, h.height);
    } else if (key == "POINTS") {
      single(h.has_points, h.points);
    } else if (key == "DATA") {
      if (n != 1 || (words[1] != "ascii" && words[1] != "binary" &&
                     words[1] != "binary_compressed"))
        lines.fail("DATA must be ascii, binary or binary_compressed");
      h.data = std::string(words[1]);
    } else {
      lines.fail("unknown header line '" + std::string(line.substr(0, 40)) + "'");
    }
  }
  return h;
}

/// The blob's fields, offsets, width and height from a checked header.
void
pcdLayout(const HeaderLines& lines, PcdHeader& h, pcl::PCLPointCloud2& blob)
{
  const std::size_t n = h.names.size();
  if (n == 0)
    lines.fail("no FIELDS line");
  if (h.counts.empty())
    h.counts.assign(n, 1);
  if (h.sizes.size() != n || h.types.size() != n || h.counts.size() != n)
    lines.fail(std::to_string(n) + " FIELDS but " + std::to_string(h.sizes.size()) +
               " SIZE, " + std::to_string(h.types.size()) + " TYPE and " +
               std::to_string(h.counts.size()) + " COUNT values");
  if (!h.has_width) {
    if (!h.has_points)
      lines.fail("neither WIDTH nor POINTS");
    h.width = h.points;
    h.height = 1;
  }
  if (h.has_points && h.points != h.width * h.height)
    lines.fail("POINTS " + std::to_string(h.points) + " is not WIDTH x HEIGHT = " +
               std::to_string(h.width) + " x " + std::to_string(h.height));
  std::uint64_t step = 0;
  for (std::size_t k = 0; k < n; ++k) {
    const std::uint8_t datatype = datatypeOf(h.types[k], h.sizes[k]);
    if (datatype == 0)
      lines.fail("field '" + h.names[k] + "' has TYPE '" + std::string(1, h.types[k]) +
                 "' with SIZE " + std::to_string(h.sizes[k]) +
                 " (expected F 4|8, I or U 1|2|4|8)");
    if (h.counts[k] == 0)
      lines.fail("field '" + h.names[k] + "' has COUNT 0");
    pcl::PCLPointField f;
    f.name = h.names[k];
    f.offset = static_cast<std::uint32_t>(step);
    f.datatype = datatype;
    f.count = static_cast<std::uint32_t>(h.counts[k]);
    blob.fields.push_back(f);
    step += h.sizes[k] * h.counts[k]; // each term <= 8 * 2^20: no overflow
    if (step > kMaxPointStep)
      lines.fail("a point of more than " + std::to_string(kMaxPointStep) + " bytes");
  }
  blob.point_step = static_cast<std::uint32_t>(step);
  blob.width = static_cast<std::uint32_t>(h.width);
  blob.height = static_cast<std::uint32_t>(h.height);
  blob.row_step = blob.width * blob.point_step; // <= kMaxScanDataBytes once checked
}

/// binary_compressed: LZF of the point data stored field by field, unpacked to points.
void
pcdCompressedBody(const HeaderLines& lines,
                  std::string_view bytes,
                  std::size_t data_idx,
                  pcl::PCLPointCloud2& blob)
{
  const std::uint64_t available = bytes.size() - data_idx; // >= 8, checked by the caller
  std::uint32_t compressed = 0, uncompressed = 0;
  std::memcpy(&compressed, bytes.data() + data_idx, 4);
  std::memcpy(&uncompressed, bytes.data() + data_idx + 4, 4);
  if (compressed == 0 || compressed > available - 8)
    lines.fail("truncated binary_compressed data: size " + std::to_string(compressed) +
               " is not within the " + std::to_string(available - 8) +
               " bytes that follow");
  if (uncompressed != blob.data.size())
    lines.fail("binary_compressed data unpacks to " + std::to_string(uncompressed) +
               " bytes, the header declares " + std::to_string(blob.data.size()));
  std::vector<std::uint8_t> unpacked(uncompressed);
  const unsigned int got = pcl::lzfDecompress(
      bytes.data() + data_idx + 8, compressed, unpacked.data(), uncompressed);
  if (got != uncompressed)
    lines.fail("binary_compressed data is corrupt (LZF gave " + std::to_string(got) +
               " of " + std::to_string(uncompressed) + " bytes)");
  // Stored field by field: all points' first field, then all points' second, ...
  const std::size_t num_points = blob.data.size() / blob.point_step;
  const std::uint8_t* in = unpacked.data();
  for (const pcl::PCLPointField& f : blob.fields) {
    const std::size_t size = pcl::getFieldSize(f.datatype) * f.count;
    for (std::size_t i = 0; i < num_points; ++i, in += size)
      std::memcpy(blob.data.data() + i * blob.point_step + f.offset, in, size);
  }
}

// ---------------------------------------------------------------------------- PLY

struct PlyProperty
{
  std::uint8_t datatype = 0;      ///< of the value, or of the list items
  std::uint8_t list_datatype = 0; ///< of the list length; 0 when not a list
  std::string name;
};

struct PlyElement
{
  std::string name;
  std::uint64_t count = 0;
  std::vector<PlyProperty> properties;
};

std::uint8_t
plyDatatype(std::string_view t)
{
  using F = pcl::PCLPointField;
  if (t == "char" || t == "int8")
    return F::INT8;
  if (t == "uchar" || t == "uint8")
    return F::UINT8;
  if (t == "short" || t == "int16")
    return F::INT16;
  if (t == "ushort" || t == "uint16")
    return F::UINT16;
  if (t == "int" || t == "int32")
    return F::INT32;
  if (t == "uint" || t == "uint32")
    return F::UINT32;
  if (t == "float" || t == "float32")
    return F::FLOAT32;
  if (t == "double" || t == "float64")
    return F::FLOAT64;
  return 0;
}

/// The header after the magic line up to end_header: the elements and the format.
std::vector<PlyElement>
readPlyHeader(HeaderLines& lines, std::string& format)
{
  std::string_view line;
  std::vector<PlyElement> elements;
  for (;;) {
    if (!lines.next(line))
      lines.fail("no end_header line");
    const std::vector<std::string_view> w = splitWords(line);
    if (w.empty() || w[0] == "comment" || w[0] == "obj_info")
      continue;
    if (w[0] == "end_header")
      break;
    if (w[0] == "format") {
      if (w.size() != 3 || (w[1] != "ascii" && w[1] != "binary_little_endian" &&
                            w[1] != "binary_big_endian"))
        lines.fail("format must be ascii, binary_little_endian or binary_big_endian");
      format = std::string(w[1]);
    } else if (w[0] == "element") {
      PlyElement e;
      if (w.size() != 3 ||
          !parseCount(w[2], std::numeric_limits<std::uint32_t>::max(), e.count))
        lines.fail("element needs a name and a count from 0 to 4294967295 (line " +
                   std::to_string(lines.lineNumber()) + ")");
      e.name = std::string(w[1]);
      elements.push_back(std::move(e));
    } else if (w[0] == "property" && !elements.empty()) {
      PlyProperty p;
      const bool list = w.size() == 5 && w[1] == "list";
      if (!(list || w.size() == 3))
        lines.fail("malformed property line " + std::to_string(lines.lineNumber()));
      p.datatype = plyDatatype(w[list ? 3 : 1]);
      p.list_datatype = list ? plyDatatype(w[2]) : 0;
      if (p.datatype == 0 || (list && (p.list_datatype == 0 ||
                                       p.list_datatype == pcl::PCLPointField::FLOAT32 ||
                                       p.list_datatype == pcl::PCLPointField::FLOAT64)))
        lines.fail("unknown property type on line " + std::to_string(lines.lineNumber()));
      p.name = std::string(w.back());
      elements.back().properties.push_back(std::move(p));
    } else {
      lines.fail("unknown header line '" + std::string(line.substr(0, 40)) + "'");
    }
  }
  return elements;
}

} // namespace

void
parsePcd(const std::string& path,
         std::string_view bytes,
         pcl::PCLPointCloud2& blob,
         std::string_view* binary_data)
{
  if (binary_data)
    *binary_data = {};
  HeaderLines lines(path, bytes, ".pcd");
  PcdHeader header = readPcdHeader(lines);
  pcdLayout(lines, header, blob);
  const std::uint64_t num_points = header.width * header.height;
  const std::size_t data_idx = lines.offset();
  const std::uint64_t available = bytes.size() - data_idx;
  if (num_points == 0)
    return;
  if (header.data == "ascii") {
    // At least one character and a separator per value.
    std::uint64_t values = 0;
    for (const pcl::PCLPointField& f : blob.fields)
      values += f.count;
    allocatePoints(lines, blob, num_points, available, 2 * values);
    parseAsciiPoints(lines, blob, num_points);
  } else if (header.data == "binary") {
    if (binary_data) {
      checkPointCount(lines, blob, num_points, available, blob.point_step);
      *binary_data = bytes.substr(data_idx, num_points * blob.point_step);
      return;
    }
    allocatePoints(lines, blob, num_points, available, blob.point_step);
    std::memcpy(blob.data.data(), bytes.data() + data_idx, blob.data.size());
  } else {
    if (available < 8)
      lines.fail("binary_compressed data shorter than its 8-byte size header");
    const std::uint64_t max_unpacked = kMaxLzfRatio * (available - 8) + 64;
    if (num_points > max_unpacked / blob.point_step)
      lines.fail(std::to_string(available) +
                 " bytes of binary_compressed data cannot hold " +
                 std::to_string(num_points) + " points of " +
                 std::to_string(blob.point_step) + " bytes");
    allocatePoints(lines, blob, num_points, available, 0);
    pcdCompressedBody(lines, bytes, data_idx, blob);
  }
}

void
parsePly(const std::string& path, std::string_view bytes, pcl::PCLPointCloud2& blob)
{
  HeaderLines lines(path, bytes, ".ply");
  std::string_view line;
  if (!lines.next(line) || line != "ply")
    lines.fail("the first line is not 'ply'");
  std::string format;
  const std::vector<PlyElement> elements = readPlyHeader(lines, format);
  if (format.empty())
    lines.fail("no format line");
  const auto vertex =
      std::find_if(elements.begin(), elements.end(), [](const PlyElement& e) {
        return e.name == "vertex";
      });
  if (vertex == elements.end())
    lines.fail("no vertex element");
  if (vertex != elements.begin())
    lines.fail("the vertex element is not the first element");
  std::uint64_t step = 0;
  for (const PlyProperty& p : vertex->properties) {
    if (p.list_datatype)
      lines.fail("vertex property '" + p.name + "' is a list (not supported in a scan)");
    pcl::PCLPointField f;
    f.name = p.name;
    f.offset = static_cast<std::uint32_t>(step);
    f.datatype = p.datatype;
    f.count = 1;
    blob.fields.push_back(f);
    step += pcl::getFieldSize(p.datatype);
  }
  if (step == 0)
    lines.fail("the vertex element has no properties");
  blob.point_step = static_cast<std::uint32_t>(step);
  blob.height = 1;
  const std::uint64_t available = bytes.size() - lines.offset();
  if (format == "ascii") {
    allocatePoints(lines, blob, vertex->count, available, 2 * vertex->properties.size());
    parseAsciiPoints(lines, blob, vertex->count);
  } else {
    allocatePoints(lines, blob, vertex->count, available, step);
    if (!blob.data.empty()) // memcpy to the null data() of no vertices is undefined
      std::memcpy(blob.data.data(), bytes.data() + lines.offset(), blob.data.size());
    if (format == "binary_big_endian")
      for (std::size_t i = 0; i < vertex->count; ++i)
        for (const pcl::PCLPointField& f : blob.fields) {
          std::uint8_t* v = blob.data.data() + i * step + f.offset;
          std::reverse(v, v + pcl::getFieldSize(f.datatype));
        }
  }
  blob.width = static_cast<std::uint32_t>(vertex->count);
  blob.row_step = blob.width * blob.point_step;
}

} // namespace io_detail
} // namespace rast
} // namespace pcl
