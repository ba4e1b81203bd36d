/// @file streamed_build.h
/// @brief buildModel over a dense volume read slab by slab, so that memory follows the surface rather than
/// the volume: the samples of one slab of z-slices, with the halo the reference's stencils need, are held at
/// a time; what a slab leaves behind is its crossed cells and edges, their isovertices and the reference's
/// data at their corners. The model is buildModel's of the whole volume byte for byte, for any thread count
/// and any slab thickness (each slab is a brick of the whole volume with enough apron, and global choices —
/// Auto's estimate, the two-valued detection of masks — are made in a first pass over the slabs, in the
/// whole-volume build's order).
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "cip/model/model_builder.h"

namespace cip {

/// Reads the samples of slices [z0, z1) of the volume into `out` (dims[0] * dims[1] * (z1 - z0) doubles, x
/// fastest), as the whole-volume reader would give them: SlabReader::readInto (readers/slab_reader.h). Slabs
/// are asked for in increasing z within each pass.
using SliceSource = std::function<void(std::int64_t z0, std::int64_t z1, double* out)>;

struct StreamOptions {
  /// Cells along z each slab owns; 0: as many as keep the slab's samples (halo included) near slabBytes, and
  /// at least half as many as the slices of its halo (the window then exceeds slabBytes for wide slices).
  std::int64_t slabCells = 0;
  std::size_t slabBytes = std::size_t(64) << 20;
};

/// What one process of a streamed build read (docs/mpi.md): with BuildOptions::collective of N ranks, rank r
/// builds the cell layers of its rankShare along z and reads only the slices they and their halo need.
struct RankSlices {
  std::int64_t cellBegin = 0, cellEnd = 0;    ///< the cell layers along z it built: [cellBegin, cellEnd)
  std::int64_t slabs = 0;                     ///< its slabs in the building pass
  std::int64_t firstSlice = 0, endSlice = 0;  ///< every slice it read lies in [firstSlice, endSlice)
  std::int64_t slicesRead = 0;                ///< slices it read, over all passes
};

/// How a streamed build went (for --stats-json).
struct StreamStats {
  std::int64_t slabs = 0;       ///< slabs per pass over the volume
  std::int64_t slabCells = 0;   ///< cells along z each slab owns (the last may own fewer)
  int halo = 0;                 ///< slices read beyond the slab's cells on either side
  int passes = 0;               ///< passes over the volume: 2 when a global choice needs a first one
  std::size_t windowBytes = 0;  ///< samples held at once: the slab and halo, and the mask's field of it
  double readSeconds = 0;       ///< time spent in the slice source
  /// What each rank read, in rank order (one entry without a collective); the fields above are this rank's.
  std::vector<RankSlices> ranks;
};

/// Why `options` cannot be built slab by slab (exact normals need an analytic field; the paper's interior
/// central rule reads samples after the scan), or empty when it can.
std::string whyNotStreamed(const BuildOptions& options);

/// buildModel(grid, options) of the volume of `geometry` whose samples `read` gives, one slab at a time.
/// With options.collective of more than one rank, every rank calls it with the same arguments but its own
/// `read`, which is asked only for the slices of the rank's share of the cell layers and their halo; the
/// ranks exchange what their slabs left and each ends with the model one process builds, bit for bit.
/// Throws as buildModel does, cip::Error for options whyNotStreamed rejects, and whatever `read` throws.
Model buildModelStreamed(const GridGeometry& geometry, const SliceSource& read, const BuildOptions& options,
                         const std::string& source, const StreamOptions& stream = {},
                         StreamStats* stats = nullptr);

}  // namespace cip
