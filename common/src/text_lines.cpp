/// \file text_lines.cpp
/// \brief readBoundedLine: std::getline that stops at kMaxTextLineBytes.

#include <pcl/rast/text_lines.h>
#include <stdexcept>

namespace pcl {
namespace rast {

bool
readBoundedLine(std::istream& in,
                std::string& line,
                const std::string& path,
                std::size_t line_number)
{
  line.clear();
  std::streambuf* buffer = in.rdbuf();
  if (!in || !buffer)
    return false;
  for (;;) {
    const int c = buffer->sbumpc();
    if (c == std::char_traits<char>::eof()) {
      in.setstate(std::ios::eofbit);
      if (line.empty())
        return false;
      break;
    }
    if (c == '\n')
      break;
    if (line.size() >= kMaxTextLineBytes)
      throw std::runtime_error("'" + path + "' line " + std::to_string(line_number) +
                               " is longer than " + std::to_string(kMaxTextLineBytes) +
                               " bytes (not a text file?)");
    line.push_back(static_cast<char>(c));
  }
  if (!line.empty() && line.back() == '\r')
    line.pop_back();
  return true;
}

} // namespace rast
} // namespace pcl
