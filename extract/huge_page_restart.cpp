#include "huge_page_restart.h"

#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>

namespace cip {

namespace {

/// Huge pages for the heap; and the heap keeps what is freed (blocks up to 32 MiB come from it, it grows in
/// 64 MiB steps and is never trimmed), so that a table freed by one pass is reused by the next instead of
/// being returned and faulted in, zeroed, again: a gyroid at N = 192 took 9,400 page faults, now 2,100.
constexpr const char* kTunable =
    "glibc.malloc.hugetlb=1:glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=4294967296:"
    "glibc.malloc.top_pad=67108864";

/// Bytes of an input file, plus the data file an NRRD header names (detached data); 0 when it is no file.
double inputBytes(const std::string& path) {
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (ec) return 0;
  double bytes = static_cast<double>(size);
  const std::filesystem::path p(path);
  if (p.extension() != ".nhdr") return bytes;
  std::ifstream in(path);
  std::string line;
  for (int n = 0; n < 256 && std::getline(in, line); ++n) {
    if (line.rfind("data file:", 0) != 0 && line.rfind("datafile:", 0) != 0) continue;
    std::string name = line.substr(line.find(':') + 1);
    name.erase(0, name.find_first_not_of(' '));
    const auto data = p.parent_path() / name;
    const auto dataSize = std::filesystem::file_size(data, ec);
    if (!ec) bytes += static_cast<double>(dataSize);
    break;
  }
  return bytes;
}

}  // namespace

void restartWithHugePages(char** argv, const std::string& input, double analyticPoints, double minBytes) {
#if defined(__linux__) && defined(__GLIBC__)
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  const char* wanted = std::getenv("CIP_HUGE_PAGES");
  if ((tunables && std::strstr(tunables, "glibc.malloc.hugetlb")) ||
      (wanted && std::strcmp(wanted, "0") == 0))
    return;
  if (std::max(inputBytes(input), analyticPoints * 4) < minBytes) return;
  const std::string value = tunables && *tunables ? std::string(tunables) + ":" + kTunable : kTunable;
  if (setenv("GLIBC_TUNABLES", value.c_str(), 1) != 0) return;
  execv("/proc/self/exe", argv);
  // Only reached when the restart failed: go on without it, and keep the environment as it was.
  if (tunables)
    setenv("GLIBC_TUNABLES", tunables, 1);
  else
    unsetenv("GLIBC_TUNABLES");
#else
  (void)argv;
  (void)input;
  (void)analyticPoints;
  (void)minBytes;
#endif
}

}  // namespace cip
