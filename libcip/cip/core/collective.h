/// @file collective.h
/// @brief The few collective operations a build split between processes needs (docs/mpi.md): each process
/// (rank) computes its share, and all of them exchange the results as bytes, so every rank ends with what one
/// process would have computed. libcip knows no message-passing library: `extract` implements this with MPI
/// (extract/mpi_collective.cpp); libcip and everything else link without it.
#pragma once
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <functional>
#include <utility>
#include <vector>

namespace cip {

class Collective {
 public:
  virtual ~Collective() = default;
  /// This process's rank, 0 .. size() - 1.
  virtual int rank() const = 0;
  /// The number of ranks.
  virtual int size() const = 0;
  /// Every rank's `mine`, in rank order, on every rank (all ranks must call it, in the same order).
  virtual std::vector<std::vector<std::uint8_t>> allgather(const std::vector<std::uint8_t>& mine) const = 0;
};

/// The contiguous share [first, second) of `count` items that `rank` of `size` computes: the items in order,
/// cut into `size` runs whose lengths differ by at most one (the first count % size runs one longer).
std::pair<std::size_t, std::size_t> rankShare(std::size_t count, int rank, int size);

/// Whether `mine` holds on every rank (every rank calls it).
bool allRanks(const Collective& collective, bool mine);

/// Appends the bytes of `n` trivially copyable values to `out` (what allgather carries).
template <class T>
void appendBytes(std::vector<std::uint8_t>& out, const T* values, std::size_t n) {
  const auto* p = reinterpret_cast<const std::uint8_t*>(values);
  out.insert(out.end(), p, p + n * sizeof(T));
}

/// appendBytes of the size and then the values of `values`.
template <class T>
void appendVector(std::vector<std::uint8_t>& out, const std::vector<T>& values) {
  const std::uint64_t n = values.size();
  appendBytes(out, &n, 1);
  appendBytes(out, values.data(), values.size());
}

/// Reads back, in order, what appendBytes and appendVector wrote into one rank's bytes. Throws cip::Error
/// when the bytes end before a value (a rank sent less than its sizes say).
class ByteReader {
 public:
  explicit ByteReader(const std::vector<std::uint8_t>& bytes) : p_(bytes.data()), end_(p_ + bytes.size()) {}
  template <class T>
  void read(T* values, std::size_t n) {
    need(n, sizeof(T));
    if (n == 0) return;  // an empty vector's data() may be null, which memcpy must not get
    std::memcpy(static_cast<void*>(values), p_, n * sizeof(T));
    p_ += n * sizeof(T);
  }
  template <class T>
  T value() {
    T v;
    read(&v, 1);
    return v;
  }
  template <class T>
  std::vector<T> vector() {
    const auto n = value<std::uint64_t>();
    need(n, sizeof(T));
    std::vector<T> v(static_cast<std::size_t>(n));
    read(v.data(), v.size());
    return v;
  }
  bool atEnd() const { return p_ == end_; }

 private:
  /// Throws unless `n` values of `bytes` each are left.
  void need(std::uint64_t n, std::size_t bytes) const;
  const std::uint8_t* p_;
  const std::uint8_t* end_;
};

/// Items of one table, each rank holding its own range of them (`range(r)`, [first, end) of rank r), sent
/// to every rank: `pack(i, out)` appends item i's record of `recordBytes` to `out`, and every rank calls
/// `unpack(i, record)` for each item of the other ranks. Throws cip::Error when a rank sent another size.
void exchangeRanges(const Collective& collective, std::size_t recordBytes,
                    const std::function<std::pair<std::size_t, std::size_t>(int)>& range,
                    const std::function<void(std::size_t, std::vector<std::uint8_t>&)>& pack,
                    const std::function<void(std::size_t, const std::uint8_t*)>& unpack);

}  // namespace cip
