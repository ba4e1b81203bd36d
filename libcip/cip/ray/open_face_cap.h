/// @file open_face_cap.h
/// @brief Where a ray passes through a hole of the patch surface on an open face of a cell, and the piece of
/// that face that closes it.
///
/// An *open* face of a cell is one that is not a bounding plane of its patch: no crossing on its edges, so
/// its four corners share one sign, and no neighbouring patch continues the surface across it. Where the
/// patch takes the other sign somewhere on such a face, its zero set ends on the face and rays pass through
/// the surface there (docs/method.md, "Holes"). The surface is closed if it is taken to be the boundary of
/// the region above the isovalue (the patch's sign inside non-empty cells, the corners' sign inside empty
/// ones): at such a point that boundary runs along the face. These functions find where a ray meets it.
#pragma once
#include <cstdint>
#include <functional>
#include <optional>

#include "cip/core/vec3.h"
#include "cip/patch/corner_patch.h"

namespace cip {

/// A point where a ray crosses a cell face and the region above the isovalue begins or ends there.
struct FaceCap {
  double t = 0;   ///< ray parameter (units of the ray's direction)
  int face = -1;  ///< the cell face (cube_topology.h numbering: axis = face / 2, side = face % 2)
  bool positiveInside = false;  ///< whether the cell's side of the face is above the isovalue at the point
};

/// The caps where the ray enters and where it leaves the cell, if any.
struct FaceCaps {
  std::optional<FaceCap> entry, exit;
};

/// Sign (+1 above the isovalue, -1 below) of the region across `face` at `local` (cell-local coordinates of
/// a point on the face), e.g. the neighbouring cell's patch there when that cell is non-empty.
using AcrossFaceSign = std::function<int(int face, const Vec3& local)>;

/// The caps of one cell on the ray origin + t * direction (cell-local coordinates), t in [tMin, tMax]: the
/// ray enters (leaves) through an open face of the patch, and the patch's sign at that point differs from
/// the sign across the face. `config` is the cell's sign configuration (bit v: corner v above the
/// isovalue). `across` is asked only where the patch's sign differs from the face corners' sign; without it
/// the corners' sign stands for the region across (right when the cell across is empty). A zero value of
/// the patch at the point makes no cap: the patch's own zero set passes there.
/// Faces in `sealed` (bit f) are known to keep the corners' sign (e.g. from bounds at scene build) and are
/// not evaluated.
FaceCaps openFaceCaps(const CornerPatch& patch, std::uint8_t config, const Vec3& origin,
                      const Vec3& direction, double tMin, double tMax, const AcrossFaceSign& across = {},
                      std::uint8_t sealed = 0);

/// The unit normal of a cap, in cell-local (index) axes, pointing from below the isovalue to above it, as
/// the gradient of the patch does.
Vec3 capNormal(const FaceCap& cap);

}  // namespace cip
