#include "mpi_collective.h"

#include <algorithm>
#include <cstdlib>
#include <limits>
#include <string>

#include "cip/core/error.h"

#ifdef CIP_HAVE_MPI
#include <mpi.h>
#endif

namespace cip {

bool launchedByMpirun() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK"})
    if (std::getenv(name)) return true;
  return false;
}

#ifdef CIP_HAVE_MPI

namespace {

void check(int code, const char* what) {
  if (code != MPI_SUCCESS) throw Error(std::string("MPI: ") + what + " failed");
}

}  // namespace

std::unique_ptr<MpiWorld> MpiWorld::start(int* argc, char*** argv) {
  int provided = 0;
  // Collectives are called by one thread at a time (the build's calling thread); TBB's workers never call
  // MPI.
  check(MPI_Init_thread(argc, argv, MPI_THREAD_SERIALIZED, &provided), "MPI_Init_thread");
  std::unique_ptr<MpiWorld> world(new MpiWorld());
  MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN);
  check(MPI_Comm_rank(MPI_COMM_WORLD, &world->rank_), "MPI_Comm_rank");
  check(MPI_Comm_size(MPI_COMM_WORLD, &world->size_), "MPI_Comm_size");
  return world;
}

MpiWorld::~MpiWorld() {
  MPI_Finalize();
}

std::vector<std::vector<std::uint8_t>> MpiWorld::allgather(const std::vector<std::uint8_t>& mine) const {
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

void MpiWorld::barrier() const {
  check(MPI_Barrier(MPI_COMM_WORLD), "MPI_Barrier");
}

void MpiWorld::abort(int code) const {
  MPI_Abort(MPI_COMM_WORLD, code);
  std::_Exit(code);
}

#else

std::unique_ptr<MpiWorld> MpiWorld::start(int*, char***) {
  throw Error(
      "started by mpirun, but this extract was built without MPI (install libopenmpi-dev and rebuild; "
      "docs/mpi.md)");
}

MpiWorld::~MpiWorld() = default;

std::vector<std::vector<std::uint8_t>> MpiWorld::allgather(const std::vector<std::uint8_t>& mine) const {
  return {mine};
}

void MpiWorld::barrier() const {}

void MpiWorld::abort(int code) const {
  std::_Exit(code);
}

#endif

}  // namespace cip
