/// @file surface_fidelity.h
/// @brief Measures how faithfully a corner-patch model or a triangle mesh represents a known surface.
///
/// Both representations are sampled the same way, so their figures compare directly: in every non-empty cell,
/// k x k lines per axis (cell-local offsets (a + 1/2)/k) are intersected with the surface; each crossing
/// gives a sample point with the representation's normal (and, for patches, its exact mean curvature). Each
/// sample is projected onto the true surface by Newton steps on the analytic field; distances are reported in
/// voxels (the smallest grid spacing), normal errors in degrees, unoriented (the angle between the normal
/// lines).
#pragma once
#include <cstdint>
#include <vector>

#include "cip/mesh/triangle_mesh.h"
#include "cip/model/model.h"
#include "cip/patch/open_face_sign.h"
#include "cip/reference/isovertex.h"

namespace cip {

struct SurfaceSample {
  Vec3 world = Vec3::Zero();    ///< sample point, world coordinates
  Vec3 normal = Vec3::UnitX();  ///< unit normal of the representation there (world)
  double meanCurvature = 0;     ///< mean curvature (1/world units; patches only, 0 for meshes)
  std::int64_t cell = -1;       ///< index into Model::cells
};

/// Zeros of each cell's patch along its k x k x 3 axis-aligned lines (all roots, by sampling and bisection),
/// with exact normals and mean curvature from the patch's gradient and Hessian.
std::vector<SurfaceSample> samplePatchSurface(const Model& model, int linesPerAxis = 4);

/// Crossings of the same lines with a mesh whose triangles lie inside the model's cells (marching cubes or
/// patch meshes; uses mesh.triangleCell when present, else the cell containing each triangle's centroid).
/// With `vertexNormals` the normal is interpolated from the vertex normals, else it is the facet normal.
std::vector<SurfaceSample> sampleMeshSurface(const TriangleMesh& mesh, const Model& model, int linesPerAxis,
                                             bool vertexNormals);

struct ErrorSummary {
  std::size_t count = 0;
  double mean = 0, p99 = 0, max = 0;
};
/// Mean, 99th percentile and maximum of a list of non-negative errors.
ErrorSummary summarize(std::vector<double> errors);

struct FidelityMeasures {
  ErrorSummary distanceVoxels;  ///< distance from each sample to the true surface, in voxels
  ErrorSummary normalDegrees;  ///< angle between the sample normal and the true normal at the projected point
  ErrorSummary
      curvatureError;  ///< |mean curvature - true mean curvature|, times the voxel size (dimensionless)
};

/// Compares samples with the true surface {truth = isovalue}. `voxelSize` in world units.
FidelityMeasures measureFidelity(const std::vector<SurfaceSample>& samples, const ScalarField& truth,
                                 double isovalue, double voxelSize, bool withCurvature);

/// Number of non-empty cells whose patch has the wrong sign (against truth - isovalue) at some point of a
/// lattice x lattice x lattice grid in the cell that lies more than `marginVoxels` from the true surface:
/// cells that would show a spurious sheet or bubble. A disagreement counts unless Newton steps towards the
/// true surface (up to 100) reach, within the margin, the surface or the other true sign, or a ball of radius
/// `marginVoxels` around the point (sampled 1/8 of the radius apart) holds a point of the other true sign.
std::int64_t countSpuriousCells(const Model& model, const ScalarField& truth, int lattice = 8,
                                double marginVoxels = 0.5);

/// Number of bounding faces of cells (a face between two cells counts for each) on which the patch has the
/// wrong sign at some point of a lattice x lattice grid on the face more than `marginVoxels` from the true
/// surface, with the test of countSpuriousCells: the joins between cells, where a wrong sign is a sheet
/// spanning two cells. Cells listed in `skipCells` (model indices) are left out.
std::int64_t countWrongSignFaces(const Model& model, const ScalarField& truth, int lattice = 16,
                                 double marginVoxels = 0.5, const std::vector<std::uint32_t>& skipCells = {});
/// The same on the lattice with the given face coordinates (in [0, 1]) along both axes of every face.
std::int64_t countWrongSignFaces(const Model& model, const ScalarField& truth,
                                 const std::vector<double>& coordinates, double marginVoxels = 0.5,
                                 const std::vector<std::uint32_t>& skipCells = {});

/// Number of cells whose patch takes, somewhere on a face that is not one of its bounding planes (an "open"
/// face: no crossing on its edges, so its four corners share one sign), the other sign than those corners, at
/// a point of a lattice x lattice grid on the face that includes its border. No neighbouring patch continues
/// the surface across such a face (the cell across has no crossing there, or none joined to this one), so
/// the patch's zero set ends on it: a hole that rays pass through. Needs no reference: marching cubes'
/// surface never meets an open face.
std::int64_t countOpenFaceLeaks(const Model& model, int lattice = kOpenFaceLattice);
/// The cells countOpenFaceLeaks counts (indices into Model::cells, increasing).
std::vector<std::uint32_t> openFaceLeakCells(const Model& model, int lattice = kOpenFaceLattice);

/// Newton steps along the gradient from p (world) onto the surface truth = iso (at most 30; stops when a step
/// is below 1e-13 or the gradient vanishes). The result is a surface point when it converges, not always the
/// nearest one.
Vec3 projectToSurface(const ScalarField& truth, double iso, Vec3 p);

/// Mean curvature (div of the unit normal, halved) of an implicit function with gradient g and Hessian h at a
/// point, in the units of the coordinates g and h are taken in. Positive for a sphere with outward gradient.
double meanCurvature(const Vec3& g, const Mat3& h);

/// Gradient and Hessian of a patch converted from cell-local (index) coordinates to world coordinates.
void patchDerivativesToWorld(const Vec3& spacing, Vec3& gradient, Mat3& hessian);

}  // namespace cip
