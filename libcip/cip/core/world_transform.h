/// @file world_transform.h
/// @brief The map from a model's grid frame to the coordinates its outputs are given in: the volume's
/// orientation (GridGeometry::direction about the origin), then optionally a change of anatomical frame
/// (RAS <-> LPS <-> LAS, `--space`). Meshes, renders, bounds and camera positions go through it; the model
/// itself stays in the axis-aligned grid frame, where its patches are built and evaluated exactly.
///
/// Points map affinely (world = linear * frame + offset), directions linearly, normals by the inverse
/// transpose; a map with negative determinant (a flipped axis) reverses the winding of triangles, so meshes
/// are re-wound to keep their normals and winding outward.
#pragma once
#include <string>

#include "cip/core/grid_geometry.h"

namespace cip {

struct WorldTransform {
  Mat3 linear = Mat3::Identity();              ///< grid frame -> world, linear part
  Vec3 offset = Vec3::Zero();                  ///< world = linear * frame + offset
  Mat3 inverse = Mat3::Identity();             ///< linear^-1
  Mat3 normalMatrix = Mat3::Identity();        ///< linear^-T, for normals and gradients
  WorldSpace space = WorldSpace::Unspecified;  ///< frame of the world coordinates

  /// The file's own world (`output` = Unspecified), or that world converted to `output` (RAS, LAS or LPS).
  /// Throws cip::Error when a conversion is asked for and the geometry does not say its anatomical frame.
  static WorldTransform of(const GridGeometry& geometry, WorldSpace output = WorldSpace::Unspecified);

  Vec3 point(const Vec3& frame) const { return linear * frame + offset; }
  Vec3 toFrame(const Vec3& world) const { return inverse * (world - offset); }
  /// A world direction in the grid frame (not normalised: a ray keeps its parameter t).
  Vec3 directionToFrame(const Vec3& world) const { return inverse * world; }
  /// A grid-frame normal or gradient in the world (not normalised).
  Vec3 normal(const Vec3& frame) const { return normalMatrix * frame; }
  /// True when the map reverses orientation (odd number of flips): triangles must be re-wound.
  bool flipsOrientation() const { return linear.determinant() < 0; }
  bool isIdentity() const { return linear == Mat3::Identity() && offset == Vec3::Zero(); }
  /// A gradient in index (or cell-local) coordinates of a grid with `spacing`, as a world gradient:
  /// normalMatrix * diag(1 / spacing). Its transpose maps Hessians: H_world = J H J^T.
  Mat3 indexGradientToWorld(const Vec3& spacing) const {
    return normalMatrix * spacing.cwiseInverse().asDiagonal();
  }
  /// The 4x4 index-to-world matrix of grid `g` in this world: [linear * diag(spacing) | mapped origin].
  Eigen::Matrix4d indexToWorld(const GridGeometry& g) const;
};

/// Parses "ras", "las", "lps" (any case); throws cip::Error naming the accepted values otherwise.
WorldSpace parseWorldSpace(const std::string& name);

}  // namespace cip
