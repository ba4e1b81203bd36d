/// @file grid_geometry.h
/// @brief Where a grid of samples sits in the world: its points per axis, origin, spacing, and the
/// orientation of its index axes (rotations, flips and shear of medical volumes).
///
/// Coordinates used throughout cip:
///  - index coordinates: grid point (i,j,k) sits at (i,j,k); x fastest in memory.
///  - grid frame: origin + spacing * index (component-wise). Models are built, stored and evaluated in this
///    axis-aligned frame; indexToWorld()/worldToIndex() map to and from it. For a grid whose `direction` is
///    the identity (analytic fields, raw files, VDB, most NRRD) the grid frame *is* the world.
///  - world coordinates: origin + direction * (spacing * index), the full index-to-world affine of the file
///    (NIfTI sform/qform, NRRD `space directions`, MetaImage `TransformMatrix`, DICOM orientation), applied
///    where coordinates leave cip (meshes, renders, bounds) by WorldTransform (world_transform.h).
///  - cell-local coordinates: cell (i,j,k) is the unit cube [0,1]^3 at index offset (i,j,k).
#pragma once
#include <Eigen/LU>  // inverse() and determinant() of direction matrices
#include <array>
#include <cstdint>

#include "cip/core/vec3.h"

namespace cip {

/// The anatomical frame a file's world coordinates are given in, when it says: RAS (NIfTI; +x right, +y
/// anterior, +z superior), LPS (DICOM, MetaImage, ITK), LAS (some NRRD). Unspecified for non-medical data and
/// NRRD's scanner-xyz / 3D-right-handed spaces.
enum class WorldSpace : std::uint8_t { Unspecified = 0, RAS = 1, LAS = 2, LPS = 3 };
const char* toString(WorldSpace space);  ///< "unspecified", "RAS", "LAS", "LPS"

/// Grid placement shared by grids and models: number of grid points per axis, world origin of point (0,0,0),
/// spacing between neighbouring points per axis, and the world direction of each index axis.
struct GridGeometry {
  std::array<std::int64_t, 3> dims{0, 0, 0};  ///< grid points per axis (cells per axis = dims - 1)
  Vec3 origin = Vec3::Zero();                 ///< world position of grid point (0,0,0)
  Vec3 spacing = Vec3::Ones();                ///< world distance between neighbouring points, per axis (> 0)
  /// Column a is the world direction of index axis a (unit length, columns linearly independent; determinant
  /// -1 for a flipped axis). Readers normalise the file's axis vectors into `spacing` and this matrix.
  Mat3 direction = Mat3::Identity();
  WorldSpace space = WorldSpace::Unspecified;  ///< frame of the world coordinates, as the file gives it

  /// Index -> grid frame (axis-aligned; see the file comment).
  Vec3 indexToWorld(const Vec3& index) const { return origin + spacing.cwiseProduct(index); }
  Vec3 worldToIndex(const Vec3& world) const { return (world - origin).cwiseQuotient(spacing); }
  /// True when the grid frame is the world (no rotation, flip or shear).
  bool axisAligned() const { return direction == Mat3::Identity(); }
  std::int64_t pointCount() const { return dims[0] * dims[1] * dims[2]; }
};

/// Splits the columns of a file's index-to-world matrix (column a = world step of one index along axis a)
/// into spacing (column lengths) and direction (unit columns). Throws cip::Error "<what>: ..." when a column
/// is zero or not finite or the matrix is singular (|det of direction| < 1e-6).
void setAxes(GridGeometry& geometry, const Mat3& indexToWorldColumns, const char* what);

}  // namespace cip
