#include "cip/core/huge_pages.h"

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>

#if defined(__linux__)
#include <sys/mman.h>
#include <unistd.h>
#endif

namespace cip {

void adviseHugePages(const void* data, std::size_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  constexpr std::uintptr_t kHuge = std::uintptr_t(2) << 20;
  if (!data || bytes < 2 * kHuge) return;
  const auto begin = reinterpret_cast<std::uintptr_t>(data);
  const std::uintptr_t first = (begin + kHuge - 1) & ~(kHuge - 1), last = (begin + bytes) & ~(kHuge - 1);
  if (last > first) madvise(reinterpret_cast<void*>(first), last - first, MADV_HUGEPAGE);
#else
  (void)data;
  (void)bytes;
#endif
}

void restartWithHugePageHeap(char** argv) {
#if defined(__linux__) && defined(__GLIBC__)
  // Huge pages for the heap; the heap keeps what is freed (blocks up to 32 MiB come from it, it grows in
  // 64 MiB steps and is never trimmed), so that a table freed by one pass is reused by the next instead of
  // being returned and faulted in, zeroed, again: a gyroid extraction at N = 192 took 9,400 page faults,
  // with it about 2,100.
  constexpr const char* kTunable =
      "glibc.malloc.hugetlb=1:glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=4294967296:"
      "glibc.malloc.top_pad=67108864";
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  const char* wanted = std::getenv("CIP_HUGE_PAGES");
  if ((tunables && std::strstr(tunables, "glibc.malloc.hugetlb")) ||
      (wanted && std::strcmp(wanted, "0") == 0))
    return;
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
#endif
}

}  // namespace cip
