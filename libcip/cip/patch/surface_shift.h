/// @file surface_shift.h
/// @brief A cheap estimate of how far a cell's surface moves when its patch changes a little (a writer's
/// rounding of the patch's numbers): the first-order shift |I'(x) - I(x)| / |grad I(x)| at points of a
/// lattice near the surface. Cells where it is large are where the patch amplifies rounding (terms that
/// nearly cancel, a small gradient), so a writer keeps more bits there (model_file_v2.cpp, refined vertices).
/// An estimate, not a bound: docs/model-format.md says how the stored surface is measured.
#pragma once
#include "cip/patch/corner_patch.h"

namespace cip {

/// The largest first-order shift (cell-local units) of the zero set of `built` towards that of `stored`,
/// over the points of a 4 x 4 x 4 lattice of the cell (faces included, cell edges left out: a patch vanishes
/// to second order on an uncrossed edge) that lie within a lattice step of `built`'s surface to first order.
double surfaceShiftEstimate(const CornerPatch& built, const CornerPatch& stored);

/// surfaceShiftEstimate(built, stored) > threshold (threshold > 0), the same verdict at a fraction of the
/// cost: a lattice point within a step of the surface (|I| <= step |grad I|) can only shift by more than the
/// threshold if |I' - I| / threshold > |I| / step, so the gradient is evaluated only where the values say so
/// (with a margin for the two evaluations' rounding), and the search stops at the first point over it.
bool surfaceShiftExceeds(const CornerPatch& built, const CornerPatch& stored, double threshold);

}  // namespace cip
