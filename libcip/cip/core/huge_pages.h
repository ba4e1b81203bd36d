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
