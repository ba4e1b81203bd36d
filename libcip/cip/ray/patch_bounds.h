/// @file patch_bounds.h
/// @brief Where in its cell a corner patch can vanish: a conservative mask of the cell's 4 x 4 x 4 sub-boxes,
/// and the part of a ray that crosses the marked ones.
///
/// The renderer gives Embree the box of the marked sub-boxes instead of the whole cell and searches a ray
/// only over the stretch from its first to its last marked sub-box, so a ray that crosses the cell where the
/// patch cannot vanish costs a slab test instead of a root search. Conservative: a sub-box is left unmarked
/// only when interval arithmetic proves |patch| larger than a margin far above rounding on the whole sub-box
/// enlarged by kZeroMaskPad (docs/raycast.md, "Tighter cell bounds").
#pragma once
#include <cstdint>

#include "cip/patch/corner_patch.h"

namespace cip {

/// Sub-boxes per axis of the mask: sub-box (i, j, k) is [i/4, (i+1)/4] x [j/4, (j+1)/4] x [k/4, (k+1)/4], bit
/// i + 4 j + 16 k.
constexpr int kZeroMaskDivisions = 4;
/// Enlargement of every sub-box (cell-local units) when the patch is bounded on it: far above the rounding of
/// a ray's slab test (which pads by kCellClipPad = 1e-9) and of its re-based origin.
constexpr double kZeroMaskPad = 1e-7;

/// Bit mask of the sub-boxes on which the patch may vanish (the bound of the patch on the enlarged sub-box
/// contains [-margin, margin], margin 1e-12 of the sum of the terms' magnitude bounds; every factor's range
/// is widened by 1e-12 first). Every zero of the patch in [-kZeroMaskPad, 1 + kZeroMaskPad]^3, and every
/// point where a ray's computed polynomial could change sign through rounding, lies in a marked sub-box.
/// With `positive`, also the sub-boxes on which the bound proves the patch above the margin (the others that
/// are not in the returned mask are proven below it).
std::uint64_t patchZeroMask(const CornerPatch& patch, std::uint64_t* positive = nullptr);

namespace detail {
constexpr std::uint64_t computeFaceLayer(int face) {
  const int axis = face / 2, layer = (face & 1) ? kZeroMaskDivisions - 1 : 0;
  std::uint64_t bits = 0;
  for (int k = 0; k < kZeroMaskDivisions; ++k)
    for (int j = 0; j < kZeroMaskDivisions; ++j)
      for (int i = 0; i < kZeroMaskDivisions; ++i)
        if ((axis == 0 ? i : axis == 1 ? j : k) == layer)
          bits |= std::uint64_t{1} << (i + kZeroMaskDivisions * (j + kZeroMaskDivisions * k));
  return bits;
}
inline constexpr std::uint64_t kFaceLayers[6] = {computeFaceLayer(0), computeFaceLayer(1),
                                                 computeFaceLayer(2), computeFaceLayer(3),
                                                 computeFaceLayer(4), computeFaceLayer(5)};
}  // namespace detail

/// The 16 sub-boxes of the mask that touch cell face f (cube_topology.h numbering). A table lookup: the
/// renderer asks it for every cell test.
constexpr std::uint64_t zeroMaskFaceLayer(int face) {
  return detail::kFaceLayers[face];
}

/// Cell-local box [lo, hi] of the marked sub-boxes (unpadded); false when the mask is empty.
bool zeroMaskBox(std::uint64_t mask, Vec3& lo, Vec3& hi);

/// The stretch [s0, s1] of [t0, t1] from the ray's entry into the first marked sub-box it crosses to its exit
/// from the last one (each sub-box enlarged by `pad`, like clipRayToCell). False when it crosses none. The
/// ray origin + t * direction is in cell-local coordinates; [t0, t1] is normally its clip to the cell.
bool clipRayToZeroMask(const Vec3& origin, const Vec3& direction, double t0, double t1, std::uint64_t mask,
                       double& s0, double& s1, double pad = 1e-9);

}  // namespace cip
