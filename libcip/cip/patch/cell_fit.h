/// @file cell_fit.h
/// @brief The central coefficient of one cell of the fitted construction (docs/method.md, "The
/// construction", steps 3, 4 and 7): the patch fitted to the reference surface inside the cell and clamped
/// under sign constraints on a cell lattice, on the cell's open faces and, where the first look suggests it,
/// on a staggered lattice. model/patch_fitting.h runs it for every cell, with the side coefficients that
/// face_fit.h gave the cell's faces.
#pragma once
#include <cstdint>

#include "cip/patch/corner_patch.h"
#include "cip/reference/tricubic_reference.h"

namespace cip {

/// A cell's central coefficient and whether it meets the samples that count.
struct CellResult {
  double central = 0;
  bool ok = true;
};

/// The central coefficient of a cell (configuration `config`): the fit clamped into the interval that the
/// cell lattice's samples allow, then the open faces' samples where they can be met with it, then the
/// staggered lattice where the first look suggests it (docs/method.md, steps 3 and 7). Where no value meets
/// the cell lattice, the result is not ok and the coefficient is 0, or with `fallBackToLeastContradicted` the
/// value the fewest counting samples contradict (only for the cells still unresolved after the fallback
/// rounds, as it examines more samples). Where only the second look (the staggered lattice) finds no value,
/// the result is not ok and the coefficient is the one from before it.
CellResult fitCell(const CornerPatch& patch, std::uint8_t config, const CellReference& ref,
                   bool fallBackToLeastContradicted = false);

}  // namespace cip
