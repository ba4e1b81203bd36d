/// @file mask_reference.h
/// @brief The reference of two-valued data (segmentation masks, the labels of a label map): a smooth field
/// whose sign at every grid point is the sample's, so that the surface fitted to it lies in the band between
/// the inside and outside voxel centres, without the voxels' terraces.
///
/// Interpolating a mask as it is reproduces its terraces. Here each class of voxels (inside and outside, or
/// each label) gets its indicator smoothed with the kernel K = a G_s - (a - 1) G_{s sqrt 2} (G_s the Gaussian
/// of standard deviation s voxels, a = sqrt2 / (sqrt2 - 1)), and the field of class T is
/// f_T = K * chi_T - max over the other classes C of K * chi_C. A Gaussian alone moves the level set of a
/// smoothed indicator inwards by s^2/2 times the mean curvature sum (the MBO scheme's curvature motion); that
/// shift comes from the second moment of the kernel's central slice, which K cancels, so spheres keep their
/// radius to O(s^4 / R^3). Where the smoothing would put a voxel on the wrong side (thin plates, sharp
/// corners), the field is clamped to +-kMaskMargin on the voxel's own side: every grid point keeps its sign,
/// so the crossed cells, their configurations and the topology are the mask's. Touching classes share their
/// interface: where T and C are the two largest smoothed indicators, f_C = -f_T exactly (the same numbers,
/// negated). docs/method.md ("Masks and label maps") measures it against VTK's windowed sinc.
///
/// Narrow band: the field is computed in blocks of kMaskBlock^3 points only where the block, grown by
/// maskReach(), holds two classes; elsewhere it is +-1. Blocks run in parallel (TBB); the field does not
/// depend on the thread count.
#pragma once
#include <cstdint>
#include <functional>

#include "cip/volume/dense_grid.h"

namespace cip {

/// Standard deviation (voxels) of the smaller Gaussian of the smoothing kernel.
constexpr double kMaskSigma = 2.5;
/// The least |f| at a grid point: a voxel whose smoothed value would be nearer the other side is clamped to
/// this on its own side (f rises by about 0.27 per voxel across a plane, so 0.01 is 0.04 voxel).
constexpr double kMaskMargin = 0.01;
/// Points per axis of the blocks the field is computed in.
constexpr int kMaskBlock = 16;

/// Points around a cell that the field of the cell's corners depends on (the kernel's radius) plus the
/// reach of the Central8 derivatives taken from it: the apron bricks of sparse volumes need.
int maskReach();
/// The radius of the smoothing kernel in grid points.
int maskKernelRadius();

/// Whether the samples next to the isosurface take two values only: `below` on the non-positive side
/// (value <= isovalue) and `above` on the positive side, at every grid point with a neighbour along an axis
/// on the other side. False when no grid edge is crossed or a sample there is not finite.
struct TwoValuedSamples {
  bool twoValued = false;
  double below = 0, above = 0;
  std::int64_t points = 0;  ///< grid points next to the surface that were looked at
};
TwoValuedSamples detectTwoValued(const DenseGrid& grid, double isovalue);

/// The smoothed field of the voxels above `isovalue` (class 1) against the rest (class 0), as samples
/// isovalue + f: the grid to build a mask's model from with the same isovalue. Same geometry and description.
DenseGrid smoothMask(const DenseGrid& grid, double isovalue);

/// The field f_T of class `target` of a partition of the grid points into classes (`classOf` maps a sample
/// to its class; a label map's labels, rounded), as samples f (isovalue 0): positive exactly at the points
/// of class `target`. Beyond the grid each point takes the class of the nearest grid point.
/// With three or more classes the field of a block depends on the classes met within the kernel's radius of
/// it, so it depends on where blocks start: `firstSliceZ` is the z index of the grid's first slice in a
/// larger grid that it is a slab of, and blocks start along z where they start in that grid (a slab holding
/// the blocks of its points and their kernel's radius gives the larger grid's field there).
DenseGrid smoothClass(const DenseGrid& grid, const std::function<std::int64_t(double)>& classOf,
                      std::int64_t target, std::int64_t firstSliceZ = 0);

}  // namespace cip
