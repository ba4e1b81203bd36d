#include "mpi_collective.h"

#include <cstdlib>

#include "cip/core/error.h"
#include "cip/core/module_loader.h"

namespace cip {

bool launchedByMpirun() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK"})
    if (std::getenv(name)) return true;
  return false;
}

std::unique_ptr<MpiWorld> MpiWorld::start(int* argc, char*** argv) {
#ifdef CIP_HAVE_MPI
  const auto& mpi = moduleTable<MpiModule>("cip_mpi", "cip_mpi_module", "running under mpirun");
  return std::unique_ptr<MpiWorld>(mpi.start(argc, argv));
#else
  (void)argc;
  (void)argv;
  throw Error(
      "started by mpirun, but this extract was built without MPI (install libopenmpi-dev and rebuild; "
      "docs/mpi.md)");
#endif
}

}  // namespace cip
