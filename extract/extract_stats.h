// Statistics of one extract run, written with --stats-json.
#pragma once
#include <map>
#include <optional>
#include <string>

#include "cip/measure/model_displacement.h"
#include "cip/model/model.h"
#include "cip/model/patch_fitting.h"
#include "cip/model/streamed_build.h"

namespace cip {

struct ExtractStats {
  std::string input, inputType;
  std::array<std::int64_t, 3> dims{};
  double isovalue = 0;
  std::string normals, central, method, reconstruction;
  std::map<std::string, double> seconds;            ///< per stage
  std::map<std::string, std::size_t> bytesWritten;  ///< per output file
  std::optional<FittingStats> fitting;              ///< the fitted construction's fallback (method fitted)
  std::optional<ModelDisplacement> storage;         ///< --check-storage: the model as stored against as built
  /// --check-holes: the cells (indices into the stored model's cells) whose patch takes the other sign than
  /// the corners somewhere on an open face (surface_fidelity.h, openFaceLeakCells), and the face lattice
  /// used.
  std::optional<std::vector<std::uint32_t>> holeCells;
  int holeLattice = 0;
  int modelVersion = 2;               ///< the format the model file was written in
  std::optional<StreamStats> stream;  ///< set when the volume was built slab by slab (--stream)
  WorldTransform world;               ///< grid frame -> the world the meshes and "world" stats are given in
  int ranks = 1;                      ///< processes the build ran on (mpirun -np; docs/mpi.md)
  std::vector<std::size_t> cellsPerRank;  ///< the patch cells each rank built (rankShare of the cells)
  std::uint64_t exchangedBytes = 0;       ///< bytes rank 0 sent to the others during the build (docs/mpi.md)
  double exchangeSeconds = 0;             ///< seconds rank 0 spent in those exchanges, waiting included
  std::uint64_t sliceBytes = 0;           ///< a streamed file's bytes per z-slice, as stored (decompressed)
};

/// Writes the stats and the model's counts (the file format version, non-empty cells, isovertices, corners,
/// loops-per-cell histogram) as JSON, atomically; for the fitted method also "fitting": rounds (and whether
/// the last one was undone), blended isovertices and the cells left without a sign-correct coefficient, and,
/// when the model followed a reference of the samples (Model::reconstruction: not with exact normals), the
/// reconstruction of it and, when auto chose it, "sampling": the effective wavelength (null when infinite),
/// the sixth-to-fourth difference ratio and the cells measured (reconstruction_choice.h). With
/// --check-storage, "storage": how far the stored model's surface lies from the built one's
/// (model_displacement.h). With --check-holes, "holes": the cells whose patch leaks through an open face
/// ("open_face_leak_cells", their count; "cells", the grid index (i, j, k) of the first 1000; "lattice").
/// "stream": whether the volume was built slab by slab ("streamed") and, when it was, the slabs per pass,
/// the cells each owns, the halo slices, the passes over the file, the bytes of samples held at once and the
/// seconds spent reading. "peak_rss_bytes": the process's peak resident memory so far (getrusage).
/// "mpi": the processes the build ran on ("ranks", 1 without mpirun), the patch cells each built
/// ("cells_per_rank") and rank 0's share of the exchanges ("exchanged_bytes" it sent, "exchange_seconds";
/// docs/mpi.md); "reads_own_slabs": whether each rank read only its z-slabs and their halo (a streamed
/// volume), and then per rank, in rank order: the cell layers along z it built ("cell_layers_per_rank",
/// [first, end)), its slabs, the slices it read ("slices_read_per_rank", over all passes;
/// "read_bytes_per_rank", their bytes as stored) and the range they lie in ("slice_range_per_rank", [first,
/// end)).
void writeExtractStats(const std::string& path, const ExtractStats& stats, const Model& model);

}  // namespace cip
