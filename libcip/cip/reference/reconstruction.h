/// @file reconstruction.h
/// @brief How the reference interpolant of sampled data takes its derivatives from the samples
/// (tricubic_reference.h), as a choice that the model records and the command lines name.
#pragma once
#include <cstdint>
#include <string>

namespace cip {

/// How the reference's derivatives at the grid points come from the samples.
enum class Reconstruction : std::uint8_t {
  /// Central differences limited by Hyman's filter (above): monotone along grid lines, so the reference's
  /// crossings of every cell edge are the marching-cubes configuration's.
  Monotone = 0,
  /// 8th-order central differences (weights 4/5, -1/5, 4/105, -1/280 of s[i+j] - s[i-j]), applied along each
  /// axis in turn for the mixed derivatives: exact for polynomials up to degree 8, so the tricubic reproduces
  /// cubics. Beyond the grid the samples are reflected oddly through the border point, s[-j] = 2 s[0] - s[j],
  /// which keeps linear fields exact there. Not monotone: next to steps (CT data) and on under-sampled data
  /// it adds crossings the cell configurations cannot follow.
  Central8 = 1,
  /// Chosen per volume by buildModel from the samples near the isosurface (reconstruction_choice.h): Central8
  /// where they are smooth at the grid's scale, Monotone otherwise (Mask for two-valued data). The default.
  /// Only buildModel takes it; the functions below need Monotone or Central8.
  Auto = 2,
  /// Two-valued data (segmentation masks, one label of a label map): the reference is the smoothed indicator
  /// of the voxels inside (mask_reference.h), whose sign at every grid point is the sample's, interpolated
  /// with Central8 derivatives. Auto takes it when the samples next to the surface take only two values.
  Mask = 3,
};
const char* toString(Reconstruction kind);
/// "monotone", "central8", "auto" or "mask"; throws Error otherwise.
Reconstruction parseReconstruction(const std::string& text);

}  // namespace cip
