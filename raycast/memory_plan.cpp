#include "memory_plan.h"

#include <sys/resource.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>
#include <vector>

#include "cip/core/error.h"

namespace cip::raycast {

namespace {

// Measured on gyroid models of 10 k to 2.5 M cells (docs/raycast.md, "Memory"; benchmarks/raycast_memory.py
// compares the estimate with the peak): Embree's BVH over one user-geometry box per cell (127-151 bytes), the
// version 2 decoder's buffers besides the tables at their peak (the chunks' decoded streams, the loop
// neighbours of every vertex: 117-135 bytes per cell), the process before it reads anything (shared
// libraries, 12-14 MiB) and per pixel the image's RGBA, depth, normal, id and curvature (40 bytes) and the
// EXR writer's buffers (3-4 more).
constexpr std::uint64_t kEmbreeBytesPerCell = 152;
constexpr std::uint64_t kDecodeBytesPerCell = 140;
constexpr std::uint64_t kProcessBytes = 16u << 20;
constexpr std::uint64_t kImageBytesPerPixel = 48;

/// The first number of the line of `file` that starts with `key`, or nothing.
bool readNumberAfter(const char* file, const std::string& key, std::uint64_t& out) {
  std::ifstream in(file);
  std::string line;
  while (std::getline(in, line))
    if (line.compare(0, key.size(), key) == 0) {
      std::istringstream rest(line.substr(key.size()));
      return static_cast<bool>(rest >> out);
    }
  return false;
}

/// A number from a cgroup file; false when the file is missing or says "max".
bool readCgroupNumber(const std::string& file, std::uint64_t& out) {
  std::ifstream in(file);
  std::string text;
  if (!(in >> text) || text == "max") return false;
  try {
    out = std::stoull(text);
  } catch (const std::exception&) {
    return false;
  }
  return true;
}

/// The room (limit less usage) that the memory cgroups of this process and of each of its ancestors leave,
/// whichever is least: cgroup v2 (memory.max, memory.current) or v1 (memory.limit_in_bytes,
/// memory.usage_in_bytes), found through /proc/self/cgroup. max() when no level sets a limit.
std::uint64_t cgroupRoom() {
  std::uint64_t room = std::numeric_limits<std::uint64_t>::max();
  std::ifstream self("/proc/self/cgroup");
  std::string line;
  while (std::getline(self, line)) {
    // "hierarchy:controllers:path": v1's memory controller, or v2's single hierarchy (id 0, no controllers).
    const auto a = line.find(':'), b = line.find(':', a + 1);
    if (a == std::string::npos || b == std::string::npos) continue;
    const std::string controllers = line.substr(a + 1, b - a - 1);
    std::string path = line.substr(b + 1);
    bool v1 = false;
    for (std::size_t from = 0; from <= controllers.size();) {
      const std::size_t to = std::min(controllers.find(',', from), controllers.size());
      v1 = v1 || controllers.compare(from, to - from, "memory") == 0;
      from = to + 1;
    }
    if (!v1 && !(line.compare(0, a, "0") == 0 && controllers.empty())) continue;
    const std::vector<std::string> roots =
        v1 ? std::vector<std::string>{"/sys/fs/cgroup/memory"}
           : std::vector<std::string>{"/sys/fs/cgroup", "/sys/fs/cgroup/unified"};
    const char* limitFile = v1 ? "/memory.limit_in_bytes" : "/memory.max";
    const char* usageFile = v1 ? "/memory.usage_in_bytes" : "/memory.current";
    for (const std::string& root : roots) {
      // From the process's own cgroup up to the root of the mount (a cgroup namespace shows "/" here).
      for (std::string p = path;;) {
        std::uint64_t limit = 0, usage = 0;
        if (readCgroupNumber(root + p + limitFile, limit) && readCgroupNumber(root + p + usageFile, usage))
          room = std::min(room, limit > usage ? limit - usage : 0);
        const std::size_t slash = p.find_last_of('/');
        if (p.empty() || p == "/" || slash == std::string::npos) break;  // a path without '/' ends here too
        p.resize(slash);
      }
    }
  }
  return room;
}

}  // namespace

std::uint64_t MemoryPlan::peak() const {
  return process + model + std::max(decode, scene) + image;
}

MemoryPlan planPatchRender(const ModelTableCounts& counts, int width, int height) {
  MemoryPlan p;
  p.process = kProcessBytes;
  p.model = counts.tableBytes();
  p.decode = counts.version >= 2 ? counts.cells * kDecodeBytesPerCell : 0;
  p.scene = counts.cells * (sizeof(std::uint64_t) + kEmbreeBytesPerCell);
  p.image = static_cast<std::uint64_t>(width) * static_cast<std::uint64_t>(height) * kImageBytesPerPixel;
  return p;
}

std::uint64_t availableMemory() {
  std::uint64_t kib = 0;
  const std::uint64_t system = readNumberAfter("/proc/meminfo", "MemAvailable:", kib)
                                   ? kib * 1024
                                   : std::numeric_limits<std::uint64_t>::max();
  const std::uint64_t room = std::min(system, cgroupRoom());
  return room == std::numeric_limits<std::uint64_t>::max() ? 0 : room;
}

std::uint64_t peakResidentBytes() {
  rusage usage{};
  if (getrusage(RUSAGE_SELF, &usage) != 0) return 0;
  return static_cast<std::uint64_t>(usage.ru_maxrss) * 1024;
}

std::uint64_t parseByteSize(const std::string& text, const std::string& what) {
  const auto bad = [&]() {
    return Error(what + " '" + text + "' is not a size such as 512M, 8G or 1.5G (powers of 1024) or bytes");
  };
  std::size_t used = 0;
  double value = 0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    throw bad();
  }
  double scale = 1;
  if (used < text.size()) {
    if (used + 1 != text.size()) throw bad();
    switch (text[used]) {
      case 'k':
      case 'K':
        scale = 1024.0;
        break;
      case 'm':
      case 'M':
        scale = 1024.0 * 1024;
        break;
      case 'g':
      case 'G':
        scale = 1024.0 * 1024 * 1024;
        break;
      case 't':
      case 'T':
        scale = 1024.0 * 1024 * 1024 * 1024;
        break;
      default:
        throw bad();
    }
  }
  const double bytes = value * scale;
  if (!std::isfinite(bytes) || bytes < 1 || bytes > 9.0e18) throw bad();
  return static_cast<std::uint64_t>(bytes);
}

std::string formatBytes(std::uint64_t bytes) {
  const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  double v = static_cast<double>(bytes);
  int u = 0;
  while (v >= 1024 && u < 4) {
    v /= 1024;
    ++u;
  }
  char text[32];
  std::snprintf(text, sizeof text,
                u == 0    ? "%.0f %s"
                : v < 10  ? "%.2f %s"
                : v < 100 ? "%.1f %s"
                          : "%.0f %s",
                v, units[u]);
  return text;
}

}  // namespace cip::raycast
