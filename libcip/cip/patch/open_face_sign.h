/// @file open_face_sign.h
/// @brief Whether a patch keeps the corners' sign on the open faces of its cell. An open face has no crossing
/// on its edges, so its four corners share one sign and no neighbouring patch continues a surface across it:
/// where the patch takes the other sign there, its zero set ends on the face and rays see through (a hole).
/// The measure of holes (surface_fidelity.h) and a writer that must not open holes by rounding a patch's
/// numbers (model_file_v2.cpp) share these tests.
#pragma once
#include <cstdint>

#include "cip/patch/corner_patch.h"

namespace cip {

/// Points per face axis of the measure of holes (extract --check-holes), border included: 1/32 apart.
constexpr int kOpenFaceLattice = 33;

/// Whether `patch` takes the other sign than the corners of open face f (not one of its bounding planes) at
/// a point of a lattice x lattice grid of the face that includes its border (lattice >= 2). `config` is the
/// cell's sign configuration (bit v: vertex v positive). A value of exactly 0 does not count.
/// Summed per face by separable products; the points those sums do not decide by far more than their
/// rounding are evaluated with CornerPatch::value, whose sign is the verdict.
bool openFaceLeaks(const CornerPatch& patch, std::uint8_t config, int f, int lattice);

/// The open faces of the cell (bit f) on which `patch` may come near the other sign, on a 9 x 9 lattice of
/// the face (1/8 apart, border included): at a point inside the face its value with the corners' sign is
/// below `inside` times the largest magnitude inside, at a point on an edge of the face (where it meets a
/// neighbouring face; its corners left out) below `border` times the largest magnitude of the lattice, or
/// at one of its corners it has the other sign. The patch is summed per face by separable products. A
/// screen, not a proof: a patch can dip through a face between its points. On the MRI and the smoke volume
/// of docs/method.md ("Holes the file made") the faces it flags with 5 % inside and 1 % on the edges (4 %
/// and 6 % of their open faces) held every hole that rounding opened.
unsigned openFacesNearOtherSign(const CornerPatch& patch, std::uint8_t config, double inside, double border);

}  // namespace cip
