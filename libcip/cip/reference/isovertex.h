/// @file isovertex.h
/// @brief Isovertices (edge crossings) and their corner planes, shared by the four cells around a grid edge.
#pragma once
#include <array>
#include <cstdint>
#include <string>

#include "cip/volume/dense_grid.h"
#include "cip/volume/scalar_field.h"

namespace cip {

/// How the corner plane's normal at an isovertex is chosen.
enum class NormalMode : std::uint8_t {
  Edge = 0,      ///< along the crossed edge, towards its positive vertex (corner I-patch paper, section 7.1)
  Gradient = 1,  ///< central-difference gradients at the edge's two grid points, interpolated along the edge
  Exact = 2,     ///< exact edge root and exact gradient of an analytic field (paper, section 7.4)
};
const char* toString(NormalMode mode);
/// Parses "edge", "gradient" or "exact"; throws cip::Error otherwise.
NormalMode parseNormalMode(const std::string& text);

/// An isovertex with its corner plane S(x) = normal . (x - position) and corner coefficient.
struct IsoVertex {
  Vec3 position = Vec3::Zero();  ///< index coordinates (on a grid edge)
  Vec3 normal = Vec3::UnitX();   ///< unit normal in index space, pointing to the positive side
  double weight = 1.0;           ///< corner coefficient a_c, shared by the cells around the edge
};

/// Parameter in [0,1] of the isovalue crossing on an edge with end values v0, v1 (linear interpolation).
double linearCrossing(double v0, double v1, double isovalue);

/// Root of field - isovalue on the world segment a..b, bracketed by the caller (signs differ at the ends);
/// returns its parameter in [0,1] to double precision (Illinois regula falsi with bisection safeguard).
double exactCrossing(const ScalarField& field, const Vec3& a, const Vec3& b, double isovalue);

/// Makes `normal` (index space) a unit vector pointing into the half-space of `towardsPositive` (a unit edge
/// direction towards the edge's positive vertex) by at least a minimal angle; a zero or non-finite normal
/// becomes the edge direction. A corner plane that leans the wrong way would give the patch the wrong sign at
/// its own isovertex.
Vec3 orientCornerNormal(const Vec3& normal, const Vec3& towardsPositive);

/// The normal of an isovertex that lies on grid point p of `grid` (its sample equals the isovalue, so p
/// counts as below it) on an edge along `axis`, kept from tilting the corner plane across the grid edges
/// from p that do not cross the isovalue: along such an edge both ends are below, and a normal with a
/// positive component along it gives the plane, and so the patch, the other sign right next to p, where no
/// side coefficient can help (the face restriction vanishes at p and starts off with the plane's slope). Such
/// components are removed (neighbours beyond the grid are left out) and the result oriented as
/// orientCornerNormal does.
Vec3 normalClearOfUncrossedEdges(const DenseGrid& grid, const std::array<std::int64_t, 3>& p, int axis,
                                 double isovalue, const Vec3& normal, const Vec3& towardsPositive);

}  // namespace cip
