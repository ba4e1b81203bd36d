/// @file mapped_file.h
/// @brief A whole file mapped read-only into memory: the kernel pages it in from the page cache as it is
/// read, so a reader that walks it once never holds a second copy of its bytes (a model file decoded into
/// its tables, a volume read slab by slab). Empty files map to an empty range.
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>

namespace cip {

class MappedFile {
 public:
  /// Maps `path`; throws cip::Error "<path>: cannot open: <reason>" (or "cannot map") on failure.
  explicit MappedFile(const std::string& path);
  ~MappedFile();
  MappedFile(const MappedFile&) = delete;
  MappedFile& operator=(const MappedFile&) = delete;

  const std::uint8_t* data() const { return data_; }
  std::size_t size() const { return size_; }
  /// Asks the kernel to start reading the whole file in (MADV_WILLNEED): a reader that will touch every
  /// page then waits less on page faults.
  void prefetch() const;

 private:
  const std::uint8_t* data_ = nullptr;
  std::size_t size_ = 0;
};

}  // namespace cip
