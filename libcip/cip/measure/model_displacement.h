/// @file model_displacement.h
/// @brief How far one model's surface lies from another's on the same grid: the check that a stored (possibly
/// quantised) model is the model that was built, independent of how it was stored.
///
/// Cells are matched by grid index. Through every cell present in both, rays are cast along the 3 axes and
/// the 4 cube diagonals, each on a k x k grid of lines across the cell's projection with a deterministic
/// jitter inside each stratum (about 90 rays through the cell for k = 4), and intersected exactly with both
/// patches (intersectRayPatch, sign crossings only, as the renderer does). From the first hits:
///  - depth: |t_reference - t_stored| along the ray when both are hit (voxels), and the angle between the two
///    normals there. Both blow up at grazing rays, where a tiny shift moves the hit far along the ray or onto
///    another sheet, so they are reported but do not make the verdict;
///  - distance: for each hit on one surface, its distance to the other patch's zero set, both directions (a
///    two-sided Hausdorff estimate over the sampled points). It is the smaller of the distance to the other
///    hit on the same ray and the distance to where Newton steps x <- x - I(x) grad I / |grad I|^2 on the
///    other patch land, when they converge (|I| / |grad I| <= 1e-10) inside the cell box enlarged by half a
///    voxel: both are points of the other zero set, so the figure is an upper bound of the true distance.
///    When Newton does not converge there and the ray has no other hit, the first-order estimate
///    |I| / |grad I| at the hit is used (counted in firstOrderEstimates);
///  - normal: the angle between the normal at each hit and the other surface's normal at the point the
///    distance was measured to (at the hit itself for first-order estimates), both directions. This one does
///    not blow up at grazing rays, and with the distance makes the verdict.
/// Rays that hit only one of the two surfaces are counted; their hits enter the distance and normal figures
/// like the others (a grazing miss next to a near-identical surface is a small distance, a hole a large one).
///
/// Distances are in voxels = index units (the quantity a codec quantises); normal angles in degrees between
/// the oriented world-space unit normals (the gradient divided by the spacing: what shading sees; the same
/// as index space on isotropic grids). Results do not depend on the number of threads.
#pragma once
#include <array>
#include <cstdint>
#include <vector>

#include "cip/measure/surface_fidelity.h"
#include "cip/model/model.h"

namespace cip {

struct DisplacementOptions {
  int raysPerAxis = 4;   ///< k: k x k lines per direction, 7 directions
  int newtonSteps = 8;   ///< at most this many Newton steps towards the other patch's zero set
  bool perCell = false;  ///< fill ModelDisplacement::cellDistance
};

struct ModelDisplacement {
  bool sameGeometry = true;               ///< origins and spacings equal (dims must be)
  std::int64_t cellsCompared = 0;         ///< cells present in both models
  std::int64_t cellsOnlyInReference = 0;  ///< non-empty in the reference, empty in the stored model
  std::int64_t cellsOnlyInStored = 0;     ///< the other way round
  std::int64_t rays = 0;                  ///< rays through compared cells' boxes
  std::int64_t bothHit = 0;               ///< rays that hit both surfaces
  std::int64_t referenceOnlyHits = 0;     ///< rays that hit the reference surface only
  std::int64_t storedOnlyHits = 0;        ///< rays that hit the stored surface only
  std::int64_t firstOrderEstimates = 0;   ///< distances from |I| / |grad I| (Newton did not converge)
  ErrorSummary depthVoxels;               ///< |t_reference - t_stored| on rays that hit both
  ErrorSummary rayNormalDegrees;          ///< angle between the normals at the two hits of such a ray
  ErrorSummary distanceVoxels;            ///< every hit to the other zero set, both directions
  ErrorSummary normalDegrees;             ///< every hit's normal against the other surface's, both ways
  ErrorSummary oneSidedDistanceVoxels;    ///< the distances of hits whose ray missed the other surface
  std::array<std::uint32_t, 3>
      worstCell{};  ///< grid index of the cell with the largest distance (0s if none moved)
  /// With DisplacementOptions::perCell: the largest distance in each reference cell (Model::cells order);
  /// 0 for cells without hits, NaN for cells the stored model does not have.
  std::vector<double> cellDistance;

  std::int64_t oneSidedHits() const { return referenceOnlyHits + storedOnlyHits; }
};

/// Compares `stored` with `reference` (same grid dims; throws cip::Error otherwise). A cell present in only
/// one of them is counted, not compared. O(cells x rays), in parallel over cells (TBB).
ModelDisplacement measureModelDisplacement(const Model& reference, const Model& stored,
                                           const DisplacementOptions& options = {});

}  // namespace cip
