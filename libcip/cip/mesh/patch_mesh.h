/// @file patch_mesh.h
/// @brief A crack-free triangle mesh of the corner-patch surface itself, sampled finer than the grid.
///
/// Method: marching cubes on a K-times refined grid (K = subdiv subcells per cell axis) restricted to the
/// model's non-empty cells. Refined point p gets one sign, a function of p only:
///  - p is a grid point: the data sign there (the cells' configuration bits);
///  - p lies on a grid edge or face whose grid points all have one sign (in particular every face and
///    edge of an empty cell): that sign. The patch is no guide there: it vanishes identically on a cell
///    edge without a crossing whose two faces are bounding planes, and at a cell corner on three bounding
///    planes, since every term has a squared factor of one of those planes;
///  - otherwise the sign of the patch of the lowest-index cell containing p (patch > 0: positive). On a
///    crossed face or edge all cells containing p are non-empty and their patches share the zero set
///    there, so one canonical cell decides for all of them.
/// Each refined edge whose ends differ in sign gets one vertex, found on the patch of the lowest-index
/// non-empty cell containing the whole edge: by regula falsi (Illinois) when that patch's values at the ends
/// have the ends' signs, else at the first sign change of the patch along the edge (16 samples), else at the
/// end whose assigned sign the patch contradicts. The last two cases (counted in
/// PatchMeshStats::unbracketedEdges) occur where a patch changes sign on a face or edge of its cell that has
/// no crossing, i.e. where the patch surface leaves its cell: the mesh follows the patch up to that face and
/// closes it there (such vertices are on the face, not on the zero set). Ambiguous refined faces are paired
/// by cutsOffDiagonal03 from the face's own crossings, loops come from buildCellLoops and are triangulated by
/// triangulateLoop (loop_triangulation.h; a centre-fan vertex is moved onto the patch by Newton steps when
/// they converge inside the refined cell). Vertices are shared by refined-edge key, so the mesh is indexed
/// and crack-free: a surface that stays inside the volume gives a closed mesh. Thin features narrower than a
/// refined cell can split off as separate components or merge (ordinary sampling limits).
///
/// Units: positions in world coordinates (index -> world by the model's geometry); normals are the exact
/// patch gradients (the polynomial of CornerPatch::derivatives, cell-local = index units) divided by the
/// spacing component-wise and normalised, pointing to the positive side (where the gradient vanishes, the
/// gradient slightly towards the cell centre); triangles are counter-clockwise seen from
/// the positive side (as in marching_cubes.h). triangleCell and vertexCell are filled. Parallel (TBB) over
/// cells; the result does not depend on the number of threads.
#pragma once
#include <cstddef>

#include "cip/mesh/triangle_mesh.h"
#include "cip/model/model.h"

namespace cip {

struct PatchMeshOptions {
  int threads = 0;  ///< worker threads; 0 = all hardware threads
};

struct PatchMeshStats {
  std::size_t refinedCells = 0;  ///< refined cells with a sign change
  std::size_t edgeVertices = 0;  ///< distinct refined-edge vertices
  /// Edge vertices whose owning patch had no matching sign change (see above).
  std::size_t unbracketedEdges = 0;
  std::size_t centreFans = 0;  ///< loops triangulated around an added centre vertex
};

/// Meshes the model's patch surface with `subdiv` (1..64) subcells per cell axis. Throws cip::Error for a bad
/// subdiv or when the mesh would need more than 2^32-1 vertices.
TriangleMesh patchMesh(const Model& model, int subdiv, const PatchMeshOptions& options = {},
                       PatchMeshStats* stats = nullptr);

}  // namespace cip
