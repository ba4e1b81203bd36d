/// @file atomic_file.h
/// @brief Write a file so that readers see either the old file or the complete new one, never a part.
/// The data goes to a temporary file in the same directory, is flushed, and is renamed over the target.
#pragma once
#include <cstdio>
#include <functional>
#include <string>

namespace cip {

/// Writes `path` atomically: `write` receives a FILE* opened on a temporary sibling file. If `write` throws
/// or any I/O fails, the temporary is removed, the previous `path` (if any) is left untouched, and cip::Error
/// is thrown. Returns the number of bytes written.
std::size_t writeFileAtomically(const std::string& path, const std::function<void(std::FILE*)>& write);

/// Writes `size` bytes to `f` or throws cip::Error (used inside writeFileAtomically callbacks).
void writeBytes(std::FILE* f, const void* data, std::size_t size);

}  // namespace cip
