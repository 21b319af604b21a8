#pragma once
/// \file atomic_file.h
/// \brief Writing a file so that it is either complete or absent.

#include <cstdio>
#include <functional>
#include <string>

namespace pcl {
namespace rast {

/// \brief Write \a content to \a path atomically: a temporary file in the same
/// folder, flushed, then renamed over \a path. Never leaves a half-written file.
/// \throws std::runtime_error naming the path on failure.
void
writeFileAtomically(const std::string& path, const std::string& content);

/// \brief writeFileAtomically for files too large to hold: \a write fills the temporary
/// file piece by piece and returns false on a write error (it may also throw).
/// \throws std::runtime_error naming the path on failure; nothing is left behind.
void
writeFileAtomically(const std::string& path, const std::function<bool(std::FILE*)>& write);

} // namespace rast
} // namespace pcl
