// extract across processes under mpirun (docs/mpi.md): MPI's world as libcip's Collective.
#pragma once
#include <cstdint>
#include <memory>

#include "cip/core/collective.h"

namespace cip {

/// Whether this process was started by mpirun/mpiexec (Open MPI's OMPI_COMM_WORLD_SIZE, PMIx's PMIX_RANK or
/// PMI's PMI_RANK in the environment). A plain run never initialises MPI and needs no MPI daemon.
bool launchedByMpirun();

/// MPI_COMM_WORLD as a Collective. Open MPI is in the module libcip_mpi.so (mpi_world.cpp;
/// cip/core/module_loader.h), loaded by start() only: a plain run does not load it.
class MpiWorld : public Collective {
 public:
  /// Loads the module and initialises MPI. Throws cip::Error when extract was built without MPI
  /// (CIP_HAVE_MPI unset) or the module cannot be loaded.
  static std::unique_ptr<MpiWorld> start(int* argc, char*** argv);
  /// The module's world finalises MPI when it is destroyed.
  ~MpiWorld() override = default;
  /// What this rank's allgathers moved so far: the bytes it sent and the seconds spent in them (waiting for
  /// the other ranks included), for --stats-json.
  virtual std::uint64_t bytesSent() const = 0;
  virtual double exchangeSeconds() const = 0;
  /// Waits until every rank got here (a rank that failed has called abort instead, ending them all).
  virtual void barrier() const = 0;
  /// Ends every rank of the run with exit code `code` (MPI_Abort): a rank that fails takes the run down.
  [[noreturn]] virtual void abort(int code) const = 0;
};

/// What the module libcip_mpi.so gives start(), through its entry point cip_mpi_module.
struct MpiModule {
  MpiWorld* (*start)(int* argc, char*** argv);  ///< initialises MPI; the caller owns the world
};

}  // namespace cip
