/// @file mask_reference.h
/// @brief The reference of two-valued data (segmentation masks, the labels of a label map): a smooth field
/// whose sign at every grid point is the sample's, so that the surface fitted to it lies in the band between
/// the inside and outside voxel centres, without the voxels' terraces.
///
/// Interpolating a mask as it is reproduces its terraces. Here each class of voxels (inside and outside, or
/// each label) gets its indicator smoothed with the kernel K_s = a G_s - (a - 1) G_{s sqrt 2} (G_s the
/// Gaussian of standard deviation s voxels, a = sqrt2 / (sqrt2 - 1)), and the field of class T at scale s is
/// f_T = K_s * chi_T - max over the other classes C of K_s * chi_C. A Gaussian alone moves the level set of a
/// smoothed indicator inwards by s^2/2 times the mean curvature sum (the MBO scheme's curvature motion); that
/// shift comes from the second moment of the kernel's central slice, which K_s cancels, so spheres keep their
/// radius to O(s^4 / R^3).
///
/// Scale: the largest scale (2.5 voxels) smooths the terraces best but bends parts whose radius of curvature
/// is a few voxels (tips, thin tubes), where a smaller one follows the shape better. The field is computed at
/// the scales kMaskScales, each divided by its slope across a plane so that all are signed distances near the
/// surface, and where two of them disagree at the points next to the surface (averaged with a Gaussian of
/// kMaskWeightSigma over those points), the smaller scale takes over: by how much the larger one moved the
/// surface is the measure of whether it was too large there.
///
/// Where the smoothing would put a voxel on the wrong side (thin plates, sharp corners), the field is clamped
/// to +-kMaskMargin on the voxel's own side: every grid point keeps its sign, so the crossed cells, their
/// configurations and the topology are the mask's. Touching classes share their interface: where T and C are
/// the two largest smoothed indicators, f_C = -f_T exactly (the same numbers, negated).
/// docs/method.md ("Masks and label maps") measures it against VTK's windowed sinc.
///
/// Narrow band: the field is computed in blocks of kMaskBlock^3 points only where the block, grown by
/// maskReach(), holds two classes; elsewhere it is +-1. Blocks run in parallel (TBB); the field does not
/// depend on the thread count.
#pragma once
#include <array>
#include <cstdint>

#include "cip/volume/dense_grid.h"

namespace cip {

/// Standard deviation (voxels) of the smaller Gaussian of the largest kernel: the scale of smooth parts.
constexpr double kMaskSigma = 2.5;
/// The kernels' scales, largest first: 2.5 where the shape allows, 2.0 and 1.5 where it bends faster.
constexpr double kMaskScales[3] = {kMaskSigma, 2.0, 1.5};
/// Where the mean over the points next to the surface of |F_2.5 - F_2.0| (voxels) rises from the first to
/// the second value, 2.0 and smaller takes over from 2.5; of |F_2.0 - F_1.5|, 1.5 from 2.0. On masks of
/// spheres of radius 10-40 the medians of these means are 0.010-0.013 and 0.019-0.023 voxel (the terraces'
/// noise); on a torus of tube radius 4, 0.047 and 0.044; on an ellipsoid 12 x 8 x 5, 0.082 and 0.051.
constexpr double kMaskSwitch[2][2] = {{0.02, 0.045}, {0.03, 0.06}};
/// Standard deviation (voxels) of the mean that decides the scale.
constexpr double kMaskWeightSigma = 3.0;
/// The least |f| at a grid point: a voxel whose smoothed value would be nearer the other side is clamped to
/// this on its own side (f, in the units of the largest kernel, rises by about 0.54 per voxel across a plane,
/// so 0.01 is 0.02 voxel).
constexpr double kMaskMargin = 0.01;
/// Points per axis of the blocks the field is computed in.
constexpr int kMaskBlock = 16;

/// Points around a cell that the field of the cell's corners depends on (the largest kernel's radius and the
/// scale mean's) plus the reach of the Central8 derivatives taken from it: the apron bricks of sparse volumes
/// need.
int maskReach();
/// The radius of the largest smoothing kernel in grid points.
int maskKernelRadius();
/// The radius in grid points of the mean that decides the scale: a point's field depends on the kernels'
/// fields this far from it.
int maskWeightRadius();

/// Whether the samples next to the isosurface take two values only: `below` on the non-positive side
/// (value <= isovalue) and `above` on the positive side, at every grid point with a neighbour along an axis
/// on the other side. False when no grid edge is crossed or a sample there is not finite.
///
/// Also how many crossed grid edges were counted and whether all their samples are integers: integer data at
/// an integer isovalue, where samples can equal the isovalue and lie on the surface (build_passes.h,
/// TwoValuedVerdict::integerSamples).
struct TwoValuedSamples {
  bool twoValued = false;
  double below = 0, above = 0;
  std::int64_t points = 0;  ///< grid points next to the surface that were looked at
  /// Crossed grid edges counted (those whose lower end lies in the box detectTwoValued was given).
  std::int64_t crossedEdges = 0;
  bool integral = true;  ///< every sample of the counted edges is an integer
};
/// Where detectTwoValued counts crossed grid edges: those whose lower end lies in the box [begin, end) of
/// grid points (a brick's own cells, so that bricks that overlap count every edge once; end -1: the grid's
/// end) on a slice whose global z index (that of the grid's slice 0 is firstSliceZ) is a multiple of
/// kSliceStride, a fixed sample of the volume that costs an eighth of a pass.
struct CountedEdges {
  static constexpr std::int64_t kSliceStride = 8;
  std::array<std::int64_t, 3> begin{0, 0, 0}, end{-1, -1, -1};
  std::int64_t firstSliceZ = 0;
};
/// The samples next to the surface of `grid`; the crossed edges are counted at an integer isovalue only
/// (elsewhere no integer sample equals it), on the edges `count` says.
TwoValuedSamples detectTwoValued(const DenseGrid& grid, double isovalue, const CountedEdges& count = {});

/// The smoothed field of the voxels above `isovalue` (class 1) against the rest (class 0), as samples
/// isovalue + f: the grid to build a mask's model from with the same isovalue. Same geometry and description.
DenseGrid smoothMask(const DenseGrid& grid, double isovalue);

/// The field f_L of label `label` of a label map (each sample rounded to the nearest integer, half away from
/// zero, is its label), as samples f (isovalue 0): positive exactly at the points of that label. Beyond the
/// grid each point takes the label of the nearest grid point.
/// With three or more labels the field of a block depends on the labels met within the kernel's radius of
/// it, so it depends on where blocks start: `firstSliceZ` is the z index of the grid's first slice in a
/// larger grid that it is a slab of, and blocks start along z where they start in that grid (a slab holding
/// the blocks within maskWeightRadius() of its points and the kernel's radius around them gives the larger
/// grid's field there).
DenseGrid smoothLabel(const DenseGrid& grid, std::int64_t label, std::int64_t firstSliceZ = 0);

}  // namespace cip
