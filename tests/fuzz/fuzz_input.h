// Shared helpers for the fuzz targets: run a parser on bytes and accept only cip::Error as a failure.
#pragma once
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <string>

namespace cip::fuzz {

/// Writes the input to a per-process file in /dev/shm (or /tmp) with the given suffix, for readers that take
/// paths.
inline std::string writeInput(const std::uint8_t* data, std::size_t size, const std::string& suffix) {
  static const std::string dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
  std::string path = dir + "/cip-fuzz-" + std::to_string(getpid()) + suffix;
  if (std::FILE* f = std::fopen(path.c_str(), "wb")) {
    if (size) std::fwrite(data, 1, size, f);
    std::fclose(f);
  }
  return path;
}

/// Volumes a fuzz input may describe are capped far below the machine's memory: a header that asks for more
/// must be rejected before anything is allocated.
constexpr std::size_t kMaxFuzzBytes = std::size_t(64) << 20;

}  // namespace cip::fuzz
