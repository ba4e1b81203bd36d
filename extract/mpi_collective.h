// extract across processes under mpirun (docs/mpi.md): MPI's world as libcip's Collective.
#pragma once
#include <cstdint>
#include <memory>

#include "cip/core/collective.h"

namespace cip {

/// Whether this process was started by mpirun/mpiexec (Open MPI's OMPI_COMM_WORLD_SIZE, PMIx's PMIX_RANK or
/// PMI's PMI_RANK in the environment). A plain run never initialises MPI and needs no MPI daemon.
bool launchedByMpirun();

/// MPI_COMM_WORLD as a Collective: MPI initialised by start() and finalised by the destructor.
class MpiWorld : public Collective {
 public:
  /// Initialises MPI. Throws cip::Error when extract was built without MPI (CIP_HAVE_MPI unset).
  static std::unique_ptr<MpiWorld> start(int* argc, char*** argv);
  ~MpiWorld() override;
  int rank() const override { return rank_; }
  int size() const override { return size_; }
  std::vector<std::vector<std::uint8_t>> allgather(const std::vector<std::uint8_t>& mine) const override;
  /// What this rank's allgathers moved so far: the bytes it sent and the seconds spent in them (waiting for
  /// the other ranks included), for --stats-json.
  std::uint64_t bytesSent() const { return bytesSent_; }
  double exchangeSeconds() const { return exchangeSeconds_; }
  /// Waits until every rank got here (a rank that failed has called abort instead, ending them all).
  void barrier() const;
  /// Ends every rank of the run with exit code `code` (MPI_Abort): a rank that fails takes the run down.
  [[noreturn]] void abort(int code) const;

 private:
  MpiWorld() = default;
  int rank_ = 0, size_ = 1;
  mutable std::uint64_t bytesSent_ = 0;
  mutable double exchangeSeconds_ = 0;
};

}  // namespace cip
