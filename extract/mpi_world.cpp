// extract's MPI side, built as the module libcip_mpi.so (cip/core/module_loader.h) that MpiWorld::start loads
// under mpirun only. Open MPI itself is used only here.
#include <mpi.h>

#include <algorithm>
#include <cstdlib>
#include <limits>
#include <string>

#include "cip/core/error.h"
#include "cip/core/module_loader.h"
#include "mpi_collective.h"

namespace cip {

namespace {

void check(int code, const char* what) {
  if (code != MPI_SUCCESS) throw Error(std::string("MPI: ") + what + " failed");
}

/// MPI_COMM_WORLD: MPI initialised by the constructor and finalised by the destructor.
class OpenMpiWorld final : public MpiWorld {
 public:
  OpenMpiWorld(int* argc, char*** argv) {
    int provided = 0;
    // Collectives are called by one thread at a time (the build's calling thread); TBB's workers never call
    // MPI.
    check(MPI_Init_thread(argc, argv, MPI_THREAD_SERIALIZED, &provided), "MPI_Init_thread");
    MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN);
    check(MPI_Comm_rank(MPI_COMM_WORLD, &rank_), "MPI_Comm_rank");
    check(MPI_Comm_size(MPI_COMM_WORLD, &size_), "MPI_Comm_size");
  }
  ~OpenMpiWorld() override { MPI_Finalize(); }
  int rank() const override { return rank_; }
  int size() const override { return size_; }
  std::vector<std::vector<std::uint8_t>> allgather(const std::vector<std::uint8_t>& mine) const override;
  std::uint64_t bytesSent() const override { return bytesSent_; }
  double exchangeSeconds() const override { return exchangeSeconds_; }
  void barrier() const override { check(MPI_Barrier(MPI_COMM_WORLD), "MPI_Barrier"); }
  [[noreturn]] void abort(int code) const override {
    MPI_Abort(MPI_COMM_WORLD, code);
    std::_Exit(code);
  }

 private:
  int rank_ = 0, size_ = 1;
  mutable std::uint64_t bytesSent_ = 0;
  mutable double exchangeSeconds_ = 0;
};

std::vector<std::vector<std::uint8_t>> OpenMpiWorld::allgather(const std::vector<std::uint8_t>& mine) const {
  const double start = MPI_Wtime();
  bytesSent_ += mine.size();
  const auto n = static_cast<std::size_t>(size_);
  std::vector<std::uint64_t> sizes(n);
  const std::uint64_t mySize = mine.size();
  check(MPI_Allgather(&mySize, 1, MPI_UINT64_T, sizes.data(), 1, MPI_UINT64_T, MPI_COMM_WORLD),
        "MPI_Allgather");
  std::vector<std::vector<std::uint8_t>> all(n);
  for (std::size_t r = 0; r < n; ++r) all[r].resize(sizes[r]);
  // MPI counts are ints: rounds of at most 1 GiB from each rank, each rank's bytes in order.
  constexpr std::uint64_t kRound = std::uint64_t{1} << 30;
  std::uint64_t largest = 0;
  for (std::uint64_t s : sizes) largest = std::max(largest, s);
  std::vector<std::uint8_t> round;
  std::vector<int> counts(n), displs(n);
  for (std::uint64_t at = 0; at < largest; at += kRound) {
    std::uint64_t sum = 0;
    for (std::size_t r = 0; r < n; ++r) {
      counts[r] = static_cast<int>(sizes[r] > at ? std::min(kRound, sizes[r] - at) : 0);
      displs[r] = static_cast<int>(std::min<std::uint64_t>(sum, std::numeric_limits<int>::max()));
      sum += static_cast<std::uint64_t>(counts[r]);
    }
    if (sum > static_cast<std::uint64_t>(std::numeric_limits<int>::max()))
      throw Error("MPI: an exchange of more than 2 GiB in one step (too many ranks for 1 GiB rounds)");
    round.resize(sum);
    const int myCount = counts[static_cast<std::size_t>(rank_)];
    const std::uint8_t* send = myCount > 0 ? mine.data() + at : mine.data();
    check(MPI_Allgatherv(send, myCount, MPI_BYTE, round.data(), counts.data(), displs.data(), MPI_BYTE,
                         MPI_COMM_WORLD),
          "MPI_Allgatherv");
    for (std::size_t r = 0; r < n; ++r)
      std::copy(round.begin() + displs[r], round.begin() + displs[r] + counts[r],
                all[r].begin() + static_cast<std::ptrdiff_t>(at));
  }
  exchangeSeconds_ += MPI_Wtime() - start;
  return all;
}

MpiWorld* startWorld(int* argc, char*** argv) {
  return new OpenMpiWorld(argc, argv);
}

}  // namespace

}  // namespace cip

CIP_MODULE_ENTRY const cip::MpiModule* cip_mpi_module() {
  static const cip::MpiModule table{&cip::startWorld};
  return &table;
}
