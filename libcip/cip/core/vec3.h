/// @file vec3.h
/// @brief The vector vocabulary of cip: 3-vectors and 3x3 matrices in double precision (Eigen).
///
/// Which space a vector lives in is said where it is declared: index coordinates (grid point (i,j,k) at
/// (i,j,k)), world coordinates (see grid_geometry.h) or cell-local coordinates (the cell as the unit cube).
#pragma once
#include <Eigen/Core>

namespace cip {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;

}  // namespace cip
