// Test helpers: what measureContinuity may report between cells that join exactly (C0 and G1 by
// construction), where only rounding is left.
#pragma once

namespace cip::test {

/// Gap, in voxels, between one cell's boundary curve and the neighbour's zero set. A patch value is a sum of
/// at most 19 terms of size O(1) in cell-local units, rounded to a few ulps each (~1e-15), and the gradient
/// across the curve is O(1), so a zero of one cell is a zero of the other to ~1e-15 voxel (measured up to
/// 7e-16); 1e-12 leaves a factor of several hundred and still sees a crack of a thousandth of that.
constexpr double kJoinGap = 1e-12;
/// Angle, in radians, between the two cells' normals there. It comes from acos of a dot product of unit
/// vectors that rounds to 1 within a few ulps: acos(1 - k eps) = sqrt(2 k eps), 3e-8 for k = 2 (measured up
/// to 3.7e-8); 1e-7 allows k = 22.
constexpr double kJoinAngle = 1e-7;

}  // namespace cip::test
