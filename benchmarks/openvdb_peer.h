// OpenVDB's volumeToMesh run on the same samples as cip, for side-by-side extraction timings. OpenVDB headers
// stay in openvdb_peer.cpp (they are slow to compile).
#pragma once
#include <memory>

#include "cip/volume/dense_grid.h"

namespace cipbench {

/// A dense grid converted once to an OpenVDB float grid (not timed), then meshed on demand.
class OpenVdbPeer {
 public:
  explicit OpenVdbPeer(const cip::DenseGrid& grid);
  ~OpenVdbPeer();
  /// Runs openvdb::tools::volumeToMesh at `isovalue` with `threads` (0 = all); returns the number of output
  /// polygons (triangles + quads) so the work cannot be optimised away.
  std::size_t mesh(double isovalue, int threads) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace cipbench
