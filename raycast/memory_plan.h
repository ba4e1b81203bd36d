/// @file memory_plan.h
/// @brief The memory a render will take, worked out from the model file's header before anything large is
/// allocated, and the memory the machine can give it: so that a model too large for the machine is refused
/// with a clear message instead of running out of memory halfway (docs/raycast.md, "Memory").
#pragma once
#include <cstdint>
#include <string>

#include "cip/model/model.h"

namespace cip::raycast {

/// Estimated peak bytes of a render, by what holds them.
struct MemoryPlan {
  std::uint64_t process = 0;  ///< the process before it reads the model (shared libraries, their globals)
  std::uint64_t model = 0;    ///< the decoded model's tables (ModelTableCounts::tableBytes)
  std::uint64_t decode = 0;   ///< what decoding a version 2 file holds besides the tables, at its peak
  std::uint64_t scene = 0;    ///< the scene: per-cell zero masks and Embree's BVH over the cell boxes
  std::uint64_t image = 0;    ///< the rendered image's channels and the EXR writer's copy of them
  /// The peak: decoding ends before the scene is built and the scene reuses what decoding freed, so the two
  /// do not add up.
  std::uint64_t peak() const;
};

/// The plan for rendering a model with `counts` (from modelTableCounts: version 1 files decode without extra
/// buffers) at width x height.
MemoryPlan planPatchRender(const ModelTableCounts& counts, int width, int height);

/// Bytes this process can still allocate without swapping: the kernel's MemAvailable, or less when a cgroup
/// (container, batch job) limits the process's memory. 0 when neither can be read.
std::uint64_t availableMemory();

/// The largest resident set this process has had so far (getrusage's ru_maxrss), in bytes.
std::uint64_t peakResidentBytes();

/// Parses a size such as "512M", "8G", "1.5G" or "2000000000" (bytes; suffixes K, M, G, T are powers of
/// 1024). Throws cip::Error naming `what` on anything else.
std::uint64_t parseByteSize(const std::string& text, const std::string& what);

/// "1.23 GiB", "456 MiB", "12 KiB", "100 B".
std::string formatBytes(std::uint64_t bytes);

}  // namespace cip::raycast
