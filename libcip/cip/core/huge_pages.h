/// @file huge_pages.h
/// @brief Large tables backed by transparent huge pages. Filling fresh memory costs a page fault per 4 KiB
/// page; on virtual machines those faults were a third of an extraction's time (docs/performance.md). Asking
/// for 2 MiB pages before the first touch makes them 512 times fewer.
#pragma once
#include <cstddef>
#include <vector>

namespace cip {

/// Asks the kernel to back the 2 MiB-aligned part of [data, data + bytes) with transparent huge pages
/// (Linux madvise(MADV_HUGEPAGE); nothing for ranges under 4 MiB or where the system does not offer them).
/// Only a hint: the contents and the program's behaviour are unchanged.
void adviseHugePages(const void* data, std::size_t bytes);

/// Replaces the process by itself (execv of /proc/self/exe with the same argv) with glibc's heap backed by
/// transparent huge pages and keeping what is freed (GLIBC_TUNABLES: glibc.malloc.hugetlb=1, a 32 MiB mmap
/// threshold, no trimming, 64 MiB top pad): glibc reads these only at start-up. Tables that adviseHugePages
/// does not reach (the many mid-sized vectors of a build or a decoded model) then cost a page fault per 2 MiB
/// instead of per 4 KiB, and a table freed by one pass is reused by the next without faulting it in again.
/// Returns when there is nothing to do: the tunable is already set (the restarted process), CIP_HUGE_PAGES=0,
/// or not Linux with glibc; or when the restart fails (the environment is then as it was, and the run goes
/// on). `argv` must be main's, unchanged. The CLIs decide when it pays (a restart loads the libraries again).
void restartWithHugePageHeap(char** argv);

/// v.reserve(n), with the new storage advised as above: call it before filling a large vector.
template <class T>
void reserveHuge(std::vector<T>& v, std::size_t n) {
  if (n <= v.capacity()) return;
  v.reserve(n);
  adviseHugePages(v.data(), v.capacity() * sizeof(T));
}

/// v.resize(n), new storage advised as above before the new elements are first written.
template <class T>
void resizeHuge(std::vector<T>& v, std::size_t n) {
  reserveHuge(v, n);
  v.resize(n);
}

}  // namespace cip
