/// @file model_builder.h
/// @brief Builds a corner-patch model from sampled volumes, in parallel (TBB). The model is identical, byte
/// for byte once written, for any number of threads: every table is ordered by grid keys, never by completion
/// order.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "cip/core/collective.h"
#include "cip/core/error.h"
#include "cip/model/model.h"
#include "cip/reference/reconstruction.h"
#include "cip/volume/scalar_field.h"
#include "cip/volume/sparse_volume.h"

namespace cip {

struct FittingStats;  // patch_fitting.h

/// Wall-clock seconds of each pass of buildModel (build_passes.h), for profiles and --stats-json.
struct BuildTimings {
  double scan = 0;         ///< crossed cells and edges
  double reference = 0;    ///< the reconstruction's choice and its data at the crossed cells' corners
  double isovertices = 0;  ///< unique edges and their isovertices
  double assemble = 0;     ///< loops and corners of each cell (paper coefficients)
  double fit = 0;          ///< fitted coefficients (PatchMethod::Fitted)
};

/// How the central coefficient w of each cell is set.
enum class CentralRule : std::uint8_t {
  Zero = 0,  ///< w = 0 (the paper's examples)
  Interior =
      1,  ///< eq. 6 at the reference surface's point on the line through the cell centre along the mean
          ///< corner normal (reference: the analytic field in exact mode, else the trilinear interpolant)
};

struct BuildOptions {
  double isovalue = 0;
  NormalMode normals = NormalMode::Gradient;
  CentralRule central = CentralRule::Zero;
  /// Coefficient construction. PatchMethod::Fitted (patch_fitting.h, the default) ignores `central`; with
  /// NormalMode::Gradient it also places isovertices on the reference interpolant along each edge
  /// (tricubic_reference.h), with its gradient. PatchMethod::Paper is the paper's construction.
  PatchMethod method = PatchMethod::Fitted;
  /// With PatchMethod::Fitted and NormalMode::Gradient: how the reference interpolant gets its derivatives
  /// from the samples (tricubic_reference.h). Monotone keeps the cells' edge crossings; Central8 follows
  /// smooth, well-sampled data more closely; Auto picks one of the two from the samples near the surface
  /// (reconstruction_choice.h; docs/method.md). Bricks (sparse volumes) need referenceReach(reconstruction)
  /// points around their cells for the model to be the whole volume's; with fewer, each brick's samples are
  /// extended at its border, and the patches still join.
  /// Reconstruction::Mask (or Auto on samples that take two values next to the surface, detectTwoValued)
  /// builds the model of the mask's smoothed indicator (mask_reference.h) instead of the samples: same cells,
  /// same signs at every grid point, no terraces. Bricks then need maskReach() points around their cells
  /// (brickApron) for the model to be the whole volume's.
  Reconstruction reconstruction = Reconstruction::Auto;
  /// When set (with PatchMethod::Fitted): the surface of the grid points whose value rounds to this label,
  /// as a label map's; `isovalue` and `reconstruction` are ignored and the reference is the label's field
  /// against the other labels (smoothLabel, mask_reference.h), so that touching labels' surfaces meet.
  std::optional<std::int64_t> label;
  /// With PatchMethod::Fitted: receives how many rounds, blended normals and unresolved faces/cells it took,
  /// and the reconstruction used.
  FittingStats* fittingStats = nullptr;
  /// When set, receives the seconds each pass of the build took.
  BuildTimings* timings = nullptr;
  /// Analytic field sampled by the grid (world coordinates); required for NormalMode::Exact.
  const ScalarField* exactField = nullptr;
  /// Cells with a NaN or infinite corner value are skipped (left empty) instead of failing the build.
  bool skipNonFinite = false;
  /// With false, cells get their loops and corners but no side or central coefficients (all 0): the isovertex
  /// table and loops are all marching cubes needs, so this is the project's marching-cubes front end.
  bool fitCoefficients = true;
  /// When set with more than one rank (docs/mpi.md): every rank builds from the same volume and the per-cell
  /// work is split between the ranks by rankShare over the model's cells (in key order) and exchanged, so
  /// that every rank ends with the model one process builds, bit for bit. All ranks must call buildModel
  /// with the same arguments.
  const Collective* collective = nullptr;
  /// Worker threads; 0 = all hardware threads.
  int threads = 0;
  /// Called with the fraction done (0..1), possibly from worker threads but never concurrently.
  std::function<void(double)> progress;
};

/// Sample points that a brick of a sparse volume must hold around the cells it owns for `options` to build
/// the same model from bricks as from the whole volume (the reach of the reference's stencils, or 1 for the
/// central differences of gradient normals): what a reader's apron should be (VolumeReadOptions::apron).
int brickApron(const BuildOptions& options);

/// Builds the model of a dense grid (all its cells). Throws NonFiniteSampleError on NaN/Inf corner values
/// unless options.skipNonFinite, and cip::Error when exact normals are asked for without a field.
Model buildModel(const DenseGrid& grid, const BuildOptions& options);

/// A NaN or infinite sample at a corner of a cell to be built (options.skipNonFinite not set).
class NonFiniteSampleError : public Error {
 public:
  NonFiniteSampleError(const std::string& message, const std::array<std::int64_t, 3>& at)
      : Error(message), cell(at) {}
  std::array<std::int64_t, 3> cell;  ///< the first such cell found (global index)
};

/// Builds one model from bricks placed in a global grid (`geometry`: global dims, origin and spacing).
Model buildModel(const GridGeometry& geometry, const std::vector<GridBrick>& bricks,
                 const BuildOptions& options, const std::string& source);

/// The patch of a cell from its corner data: loops, pairings, face coefficients (eq. 5) and, for
/// CentralRule::Zero, w = 0. Used by the builder; exposed for tests and single-cell tools.
/// `vertexData[e]` is the isovertex on cell edge e in cell-local coordinates (only crossed edges are read).
CornerPatch buildCellPatch(std::uint8_t config, const std::array<IsoVertex, 12>& vertexData,
                           std::uint8_t* pairing03Out = nullptr, CellLoops* loopsOut = nullptr,
                           bool fitCoefficients = true);

}  // namespace cip
