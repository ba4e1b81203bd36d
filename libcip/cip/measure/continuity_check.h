/// @file continuity_check.h
/// @brief Measures continuity between neighbouring cells of a model: for every pair of non-empty cells
/// sharing a face with crossings, the face is sampled, signs compared, and cell A's boundary curve on the
/// face (found by bisection along sample lines) is checked against cell B's zero set and normal.
#pragma once
#include "cip/model/model.h"

namespace cip {

struct ContinuityStats {
  int facePairs = 0;          ///< neighbouring non-empty cells whose shared face carries crossings
  int curvePoints = 0;        ///< boundary-curve points checked
  double maxGap = 0;          ///< largest |I_B| / |grad I_B| at a zero of I_A, in voxels (index units)
  double maxAngle = 0;        ///< largest angle between the two cells' gradients there, radians
  int signDisagreements = 0;  ///< face samples where the two cells' signs differ (away from the curve)
};

/// `samples` lines per face axis (and samples per line).
ContinuityStats measureContinuity(const Model& model, int samples = 24);

}  // namespace cip
