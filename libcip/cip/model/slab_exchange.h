/// @file slab_exchange.h
/// @brief What the ranks of a streamed build (streamed_build.h, docs/mpi.md) exchange when each reads only
/// its own slabs: rank r reads the slabs of its rankShare of the cell layers along z (plus their halo) and
/// harvests them; the ranks then exchange what their slabs left (crossed cells, edges with their isovertices,
/// the reference's compacted tables) and what the first pass measured (the two-valued detection's samples and
/// Auto's terms per cell), and join them in rank order, which is slab order, which is the order one process
/// harvests them in. Every rank then holds what one process harvests, to the bit. Internal to the builder.
#pragma once
#include <cstdint>
#include <vector>

#include "cip/core/collective.h"
#include "cip/model/build_passes.h"
#include "cip/model/streamed_build.h"

namespace cip::build {

/// What the slabs leave for the passes after them: crossed cells (key order), crossed edges with their
/// isovertices (slab order; sorted afterwards), the reference's tables (one per slab, compacted).
struct SlabHarvest {
  std::vector<CellRef> cells;
  std::vector<EdgeRef> edges;
  std::vector<IsoVertex> vertices;
  SampledReference reference;
  std::vector<Key> sharedPlane;  ///< edges the previous slab listed on its last plane of points
};

/// The first pass's measurements of one rank's slabs, in slab order.
struct FirstPassRecord {
  std::vector<TwoValuedSamples> twoValued;  ///< detectTwoValued of each slab
  std::vector<SamplingTerm> terms;          ///< Auto's terms of the slabs' crossed cells, in scan order
  std::int64_t cells = 0;                   ///< the cells measured
};

/// Every rank's record, in rank order, told to `verdict` and added to `estimator` (which has added nothing):
/// what one process tells them over all slabs.
void gatherFirstPass(const Collective& ranks, const FirstPassRecord& mine, TwoValuedVerdict& verdict,
                     SamplingEstimator& estimator);

/// Every rank's harvest joined into `harvest` in rank order: rank r harvested (and its `harvest` holds the
/// tables of) slabs [firstSlab[r], firstSlab[r + 1]). An edge on the plane two ranks' slabs share is listed
/// by both; the edges stay in rank order, and sortEdges keeps the lower rank's. Returns every rank's
/// `reading`, in rank order.
std::vector<RankSlices> gatherHarvests(const Collective& ranks, SlabHarvest& harvest,
                                       const std::vector<std::int64_t>& firstSlab, const RankSlices& reading);

/// The harvested edges and their isovertices in key order, each edge once: of an edge listed twice (by two
/// ranks), the first listed (the lower slab's, as one process keeps it).
void sortEdges(SlabHarvest& harvest);

}  // namespace cip::build
