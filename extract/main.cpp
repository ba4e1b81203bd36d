// extract: volume -> corner-patch model (.cip), plus optional marching-cubes and patch meshes.
#include <tbb/global_control.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <limits>
#include <memory>
#include <optional>

#include "cip/core/error.h"
#include "cip/core/progress_bar.h"
#include "cip/core/world_transform.h"
#include "cip/measure/model_displacement.h"
#include "cip/measure/surface_fidelity.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/mesh/patch_mesh.h"
#include "cip/meshio/mesh_file.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/readers/volume_reader.h"
#include "cip/volume/analytic_field.h"
#include "extract_stats.h"
#include "huge_page_restart.h"
#include "mpi_collective.h"
#include "streamed_input.h"

namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

struct Options {
  std::string input, output, mcMesh, patchMesh, statsJson;
  std::string normals = "gradient", central = "zero", method = "fitted", reconstruction = "auto";
  std::string stream = "auto";  ///< --stream
  std::int64_t slabCells = 0;   ///< --slab-cells
  std::string space;            ///< --space: world frame of the outputs (empty = the volume's own)
  std::optional<double> iso;
  int resolution = 64, subdiv = 4, threads = 0, modelVersion = 2;
  bool quiet = false, skipNonFinite = false, checkStorage = false, checkHoles = false, labels = false;
  std::optional<std::int64_t> label;  ///< --label N
  // raw input
  std::string dims, type, endian = "little", grid;
  int frame = -1;  // 4-D NIfTI / MetaImage: the frame to read
  std::vector<double> spacing, origin;
  std::uint64_t offset = 0;
  cip::MpiWorld* mpi = nullptr;  ///< set under mpirun (docs/mpi.md)
  /// Rank 0 (or a plain run): the rank that shows progress, writes the outputs and prints the summary.
  bool leader() const { return !mpi || mpi->rank() == 0; }
};

cip::Vec3 vec3(const std::vector<double>& v, const cip::Vec3& fallback, const char* what) {
  if (v.empty()) return fallback;
  if (v.size() != 3) throw cip::Error(std::string(what) + " needs three comma-separated numbers");
  return cip::Vec3(v[0], v[1], v[2]);
}

/// The volume to build from: a file's bricks, a dense file read slab by slab, or an analytic field sampled on
/// a grid.
struct Input {
  cip::SparseVolume volume;
  std::unique_ptr<cip::StreamedVolume> streamed;  ///< set when the file is built slab by slab (--stream)
  std::unique_ptr<cip::AnalyticField> field;      ///< set for analytic fields (exact normals need it)
  std::optional<double> defaultIso;               ///< the input's own isovalue, when it has one

  const cip::GridGeometry& geometry() const {
    return streamed ? streamed->layout().geometry : volume.geometry;
  }
};

/// What the command line asks the builder for, all but the isovalue (which may come from the input).
cip::BuildOptions buildOptions(const Options& opt) {
  cip::BuildOptions build;
  build.normals = cip::parseNormalMode(opt.normals);
  if (opt.central == "zero") {
    build.central = cip::CentralRule::Zero;
  } else if (opt.central == "interior") {
    build.central = cip::CentralRule::Interior;
  } else {
    throw cip::Error("unknown --central rule '" + opt.central + "' (expected zero or interior)");
  }
  build.method = opt.method == "fitted" ? cip::PatchMethod::Fitted : cip::PatchMethod::Paper;
  build.reconstruction = cip::parseReconstruction(opt.reconstruction);
  if ((build.reconstruction == cip::Reconstruction::Central8 ||
       build.reconstruction == cip::Reconstruction::Mask || opt.labels || opt.label) &&
      (build.method != cip::PatchMethod::Fitted || build.normals != cip::NormalMode::Gradient)) {
    throw cip::Error((opt.labels || opt.label ? std::string("--labels or --label")
                                              : "--reconstruction " + opt.reconstruction) +
                     " applies to --method fitted with --normals gradient (the reference of sampled data)");
  }
  if (opt.labels && opt.label) throw cip::Error("give --labels or --label N, not both");
  build.label = opt.label;
  build.skipNonFinite = opt.skipNonFinite;
  build.threads = opt.threads;
  return build;
}

/// Reads the input file, or samples the analytic field it names. Bricks of sparse inputs keep the samples
/// that `build` reads around their cells (brickApron), so the model is the one of the whole volume.
Input readInput(const Options& opt, const cip::BuildOptions& build, cip::ExtractStats& stats) {
  Input in;
  const bool isFile = std::filesystem::exists(opt.input);
  if (!isFile && (in.field = cip::makeAnalyticField(opt.input))) {
    in.volume = cip::fromDense(cip::sampleField(
        *in.field, opt.resolution,
        opt.input + " sampled at " + std::to_string(opt.resolution) + " cells per axis over [-1,1]^3"));
    in.defaultIso = in.field->defaultIsovalue();
    stats.inputType = "analytic field " + opt.input;
    return in;
  }
  if (!isFile) {
    std::string names;
    for (auto& n : cip::analyticFieldNames()) names += (names.empty() ? "" : ", ") + n;
    throw cip::Error(opt.input + ": no such file, and not an analytic field (" + names + ")");
  }
  cip::VolumeReadOptions read;
  if (!opt.dims.empty() || !opt.type.empty()) {
    if (opt.dims.empty() || opt.type.empty()) throw cip::Error("raw input needs both --dims and --type");
    cip::RawFormat f;
    f.dims = cip::parseDims(opt.dims);
    f.type = cip::parseSampleType(opt.type);
    f.endian = cip::parseEndian(opt.endian);
    f.spacing = vec3(opt.spacing, cip::Vec3::Ones(), "--spacing");
    f.origin = vec3(opt.origin, cip::Vec3::Zero(), "--origin");
    f.offset = opt.offset;
    read.raw = f;
  }
  read.vdbGrid = opt.grid;
  read.frame = opt.frame;
  read.apron = cip::brickApron(build);
  if (auto layout = cip::streamedLayout(opt.input, read, build, cip::parseStreamMode(opt.stream),
                                        opt.mpi ? opt.mpi->size() : 1)) {
    stats.inputType = cip::describeDenseVolume(layout->geometry, layout->description);
    stats.sliceBytes = static_cast<std::uint64_t>(layout->geometry.dims[0] * layout->geometry.dims[1]) *
                       cip::sampleSize(layout->type);
    in.streamed = std::make_unique<cip::StreamedVolume>(std::move(*layout));
    return in;
  }
  in.volume = cip::readVolume(opt.input, read);
  if (in.volume.isLevelSet) in.defaultIso = 0.0;
  stats.inputType = cip::describeVolume(in.volume);
  return in;
}

/// Warns when the isovalue lies outside the range of the data.
void warnOutsideRange(double iso, std::pair<double, double> range) {
  const auto [lo, hi] = range;
  if (!(iso > lo && iso < hi)) {
    std::fprintf(stderr,
                 "warning: isovalue %g is outside the data range [%g, %g]; the surface will be empty\n", iso,
                 lo, hi);
  }
}

/// The isovalue: --iso, else the input's own; warns when it lies outside the data (a streamed volume's range
/// is known after the build, which warns then).
double isovalue(const Options& opt, const Input& in) {
  double iso = 0;
  if (opt.iso) {
    iso = *opt.iso;
  } else if (in.defaultIso) {
    iso = *in.defaultIso;
  } else {
    throw cip::Error(opt.input + ": no default isovalue for this input; give one with --iso");
  }
  if (!in.streamed && opt.leader()) warnOutsideRange(iso, in.volume.range());
  return iso;
}

/// The world frame --space asks for (Unspecified = the volume's own).
cip::WorldSpace outputSpace(const Options& opt) {
  return opt.space.empty() ? cip::WorldSpace::Unspecified : cip::parseWorldSpace(opt.space);
}

/// The marching-cubes and patch meshes the command line asks for, in world coordinates.
void writeMeshes(const Options& opt, const cip::Model& model, cip::ExtractStats& stats) {
  const cip::WorldTransform& world = stats.world;  // the frame --space chose, checked before the build
  if (!opt.mcMesh.empty()) {
    auto t = Clock::now();
    cip::MarchingCubesOptions mo;
    mo.threads = opt.threads;
    mo.recordCells = false;
    cip::TriangleMesh mesh = cip::marchingCubes(model, mo);
    cip::transformMesh(mesh, world);
    stats.bytesWritten[opt.mcMesh] = cip::writeMesh(mesh, opt.mcMesh);
    stats.seconds["marching_cubes"] = secondsSince(t);
  }
  if (!opt.patchMesh.empty()) {
    auto t = Clock::now();
    cip::PatchMeshOptions po;
    po.threads = opt.threads;
    cip::TriangleMesh mesh = cip::patchMesh(model, opt.subdiv, po);
    cip::transformMesh(mesh, world);
    stats.bytesWritten[opt.patchMesh] = cip::writeMesh(mesh, opt.patchMesh);
    stats.seconds["patch_mesh"] = secondsSince(t);
  }
}

/// The one-line summary and the warnings about cells the sign checks could not satisfy.
void printSummary(const Options& opt, const cip::BuildOptions& build, const cip::Model& model,
                  const cip::ExtractStats& stats) {
  std::fprintf(stderr, "%s: %zu non-empty cells, %zu isovertices, %zu bytes\n", opt.output.c_str(),
               model.cells.size(), model.vertices.size(), stats.bytesWritten.at(opt.output));
  const std::size_t unresolved = stats.fitting ? stats.fitting->unresolvedCells.size() : 0;
  if (unresolved > 0)
    std::fprintf(stderr,
                 "%zu cells have no coefficient that keeps the reference's sign everywhere checked; they may "
                 "show small wrong-sign regions (docs/method.md)\n",
                 unresolved);
  // On smooth data central8 leaves a few in 10^4 cells so; steps (CT) make it ring, and many more.
  if (model.reconstruction == cip::Reconstruction::Central8 && unresolved * 1000 > model.cells.size())
    std::fprintf(stderr,
                 "that is %.2f %% of the cells: the data look too steep for the central8 reconstruction; "
                 "--reconstruction monotone follows steps\n",
                 100.0 * static_cast<double>(unresolved) / static_cast<double>(model.cells.size()));
  if (model.reconstruction == cip::Reconstruction::Mask &&
      build.reconstruction == cip::Reconstruction::Auto && !build.label)
    std::fprintf(stderr, "reference: mask (the samples next to the surface take two values only)\n");
  if (stats.fitting && stats.fitting->isovalueRaise > 0)
    std::fprintf(
        stderr,
        "isovalue: built at %.9g, %g of a level above %g: the samples next to the surface are integers, "
        "and so is the isovalue (every sample keeps its side; --reconstruction monotone or central8 builds "
        "at the isovalue as given; docs/method.md)\n",
        model.isovalue, stats.fitting->isovalueRaise, model.isovalue - stats.fitting->isovalueRaise);
  if (model.reconstruction && build.reconstruction == cip::Reconstruction::Auto &&
      stats.fitting->sampling.cells > 0)
    std::fprintf(stderr,
                 "reference: %s (samples near the surface: effective wavelength %.2f samples; central8 "
                 "from %.1f)\n",
                 cip::toString(*model.reconstruction), stats.fitting->sampling.wavelength,
                 cip::kCentral8Wavelength);
}

/// --check-storage: measures the model as stored (what a reader gets back from the file) against the model as
/// built.
void checkStorage(const Options& opt, const cip::Model& built, const cip::Model& stored,
                  cip::ExtractStats& stats) {
  auto t = Clock::now();
  stats.storage = cip::measureModelDisplacement(built, stored);
  stats.seconds["check_storage"] = secondsSince(t);
  if (!opt.quiet)
    std::fprintf(
        stderr,
        "storage: the stored surface moves by at most %.3g voxel (mean %.3g), its normals by at most "
        "%.3g degrees; %lld rays hit one surface only\n",
        stats.storage->distanceVoxels.max, stats.storage->distanceVoxels.mean,
        stats.storage->normalDegrees.max, static_cast<long long>(stats.storage->oneSidedHits()));
}

/// --check-holes: the cells of the model as stored whose patch leaks through an open face (a face no
/// neighbouring patch continues), where rays see through the surface (docs/method.md, "Holes").
void checkHoles(const Options& opt, const cip::Model& stored, cip::ExtractStats& stats) {
  auto t = Clock::now();
  stats.holeLattice = 33;
  stats.holeCells = cip::openFaceLeakCells(stored, stats.holeLattice);
  stats.seconds["check_holes"] = secondsSince(t);
  if (!opt.quiet)
    std::fprintf(stderr, "holes: %zu of %zu cells leak through an open face (docs/method.md, \"Holes\")\n",
                 stats.holeCells->size(), stored.cells.size());
}

/// For the tests of a failing rank only (docs/mpi.md): CIP_TEST_FAIL_RANK=r makes rank r (0 in a plain run)
/// fail after reading its input, as a bad slab or a rank out of memory would; with CIP_TEST_FAIL_HOW=kill it
/// dies of SIGKILL instead, as a rank the system killed.
void injectTestFault(const Options& opt) {
  const char* rank = std::getenv("CIP_TEST_FAIL_RANK");
  if (!rank || std::atoi(rank) != (opt.mpi ? opt.mpi->rank() : 0)) return;
  const char* how = std::getenv("CIP_TEST_FAIL_HOW");
  if (how && std::string(how) == "kill") std::raise(SIGKILL);
  throw cip::Error("failure injected for a test (CIP_TEST_FAIL_RANK)");
}

/// Builds the model, naming the flag that skips NaN cells when the input has some.
cip::Model build(const Options& opt, const Input& in, cip::BuildOptions options, cip::ExtractStats& stats) {
  cip::ProgressBar bar("building", !opt.quiet && opt.leader());  // rank 0 reports the whole build
  if (opt.leader()) options.progress = [&](double f) { bar.update(f); };
  options.collective = opt.mpi;
  cip::FittingStats fitting;
  if (options.method == cip::PatchMethod::Fitted) options.fittingStats = &fitting;
  if (options.normals == cip::NormalMode::Exact) {
    if (!in.field)
      throw cip::Error(
          "--normals exact needs an analytic field as input (sampled volumes: edge or gradient)");
    options.exactField = in.field.get();
  }
  cip::Model model;
  try {
    if (in.streamed) {
      cip::StreamOptions stream;
      stream.slabCells = opt.slabCells;
      cip::StreamStats streamStats;
      model = cip::buildModelStreamed(in.geometry(), in.streamed->source(), options,
                                      in.streamed->layout().description, stream, &streamStats);
      stats.stream = streamStats;
      if (!opt.labels && !opt.label) {
        const auto range = in.streamed->range(opt.mpi);  // every rank's part (each read its slabs)
        if (opt.leader()) warnOutsideRange(options.isovalue, range);
      }
    } else {
      model = cip::buildModel(in.volume.geometry, in.volume.bricks, options, in.volume.description);
    }
  } catch (const cip::NonFiniteSampleError& e) {
    throw cip::Error(std::string(e.what()) + "; use --skip-nonfinite to leave such cells empty");
  }
  if (options.fittingStats) stats.fitting = fitting;
  return model;
}

/// `path` with -labelN before its extension (out.cip -> out-label3.cip), for --labels.
std::string labelPath(const std::string& path, std::int64_t label) {
  const std::filesystem::path p(path);
  const std::string stem = p.stem().string() + "-label" + std::to_string(label) + p.extension().string();
  return p.has_parent_path() ? (p.parent_path() / stem).string() : stem;
}

int runOne(const Options& opt, const Input& in, cip::BuildOptions options, cip::ExtractStats stats);

int run(const Options& opt) {
  // --threads bounds every parallel part of the run (reading, sampling, the range scan), not the build alone.
  std::optional<tbb::global_control> threadLimit;
  if (opt.threads > 0) threadLimit.emplace(tbb::global_control::max_allowed_parallelism, opt.threads);
  cip::ExtractStats stats;
  stats.input = opt.input;
  auto t0 = Clock::now();
  cip::BuildOptions options = buildOptions(opt);
  // Mesh names the writers refuse fail here, before the build.
  if (!opt.mcMesh.empty()) cip::meshFormatOf(opt.mcMesh);
  if (!opt.patchMesh.empty()) cip::meshFormatOf(opt.patchMesh);
  cip::BuildOptions readOptions = options;  // the apron the bricks need
  if (opt.labels) readOptions.label = 0;
  Input in = readInput(opt, readOptions, stats);
  injectTestFault(opt);
  // A --space the volume cannot be converted to fails here, before the build.
  stats.world = cip::WorldTransform::of(in.geometry(), outputSpace(opt));
  stats.dims = in.geometry().dims;
  stats.seconds["read"] = secondsSince(t0);

  options.isovalue = opt.labels || opt.label ? 0.0 : isovalue(opt, in);
  if (opt.labels) {
    const std::vector<std::int64_t> labels =
        in.streamed ? in.streamed->labels(opt.mpi) : cip::labelsOf(in.volume);
    if (labels.empty()) throw cip::Error(opt.input + ": --labels found no non-zero label");
    for (const std::int64_t label : labels) {
      Options one = opt;
      one.labels = false;
      one.label = label;
      one.output = labelPath(opt.output, label);
      if (!opt.mcMesh.empty()) one.mcMesh = labelPath(opt.mcMesh, label);
      if (!opt.patchMesh.empty()) one.patchMesh = labelPath(opt.patchMesh, label);
      if (!opt.statsJson.empty()) one.statsJson = labelPath(opt.statsJson, label);
      options.label = label;
      runOne(one, in, options, stats);
    }
    return 0;
  }
  return runOne(opt, in, options, stats);
}

/// Builds the model `options` ask for from the volume read, writes it and what goes with it.
int runOne(const Options& opt, const Input& in, cip::BuildOptions options, cip::ExtractStats stats) {
  cip::BuildTimings timings;
  options.timings = &timings;
  stats.isovalue = options.isovalue;
  stats.normals = opt.normals;
  stats.central = opt.central;
  stats.method = opt.method;
  stats.reconstruction = opt.reconstruction;

  auto t1 = Clock::now();
  cip::Model model = build(opt, in, options, stats);
  stats.seconds["build"] = secondsSince(t1);
  stats.seconds["build_scan"] = timings.scan;
  stats.seconds["build_reference"] = timings.reference;
  stats.seconds["build_isovertices"] = timings.isovertices;
  stats.seconds["build_assemble"] = timings.assemble;
  stats.seconds["build_fit"] = timings.fit;
  stats.ranks = opt.mpi ? opt.mpi->size() : 1;
  for (int r = 0; r < stats.ranks; ++r) {
    const auto [first, end] = cip::rankShare(model.cells.size(), r, stats.ranks);
    stats.cellsPerRank.push_back(end - first);
  }
  if (opt.mpi) {
    stats.exchangedBytes = opt.mpi->bytesSent();
    stats.exchangeSeconds = opt.mpi->exchangeSeconds();
  }
  // Every rank holds the same model now; rank 0 writes it once all ranks got here (one that failed has
  // ended the run instead: no output then).
  if (opt.mpi) opt.mpi->barrier();
  if (!opt.leader()) return 0;

  // Everything after this point describes the model as the file stores it (format 2 quantises), never the
  // model as built.
  auto t2 = Clock::now();
  cip::ModelFileOptions fileOptions;
  fileOptions.version = static_cast<std::uint32_t>(opt.modelVersion);
  const std::vector<std::uint8_t> bytes = cip::serializeModel(model, fileOptions);
  stats.bytesWritten[opt.output] = cip::writeModelBytes(bytes, opt.output);
  stats.seconds["write_model"] = secondsSince(t2);
  // The surface as stored is read back only for what measures or meshes it. The summary and the statistics
  // give counts (cells, isovertices, corners, loops), the grid and the reconstruction, which the file holds
  // as built (format 2 quantises positions, normals and coefficients, never the topology): they come from the
  // built model otherwise, and read_back_model is then 0.
  const bool readBack = opt.checkStorage || opt.checkHoles || !opt.mcMesh.empty() || !opt.patchMesh.empty();
  auto t3 = Clock::now();
  cip::Model stored = readBack ? cip::parseModel(bytes.data(), bytes.size(), opt.output) : cip::Model();
  stats.seconds["read_back_model"] = readBack ? secondsSince(t3) : 0.0;
  stats.modelVersion = opt.modelVersion;
  if (opt.checkStorage) checkStorage(opt, model, stored, stats);
  if (opt.checkHoles) checkHoles(opt, stored, stats);
  if (readBack) {
    model = cip::Model();
    writeMeshes(opt, stored, stats);
  }
  const cip::Model& described = readBack ? stored : model;
  if (!opt.quiet) printSummary(opt, options, described, stats);
  if (!opt.statsJson.empty()) cip::writeExtractStats(opt.statsJson, stats, described);
  return 0;
}

/// The command line's options and flags, each with its help text and an example.
void defineOptions(CLI::App& app, Options& opt) {
  app.add_option("input", opt.input, "volume file or analytic field name, e.g. tooth.nhdr or sphere")
      ->required();
  app.add_option("-o,--output", opt.output, "model file to write (.cip), e.g. -o tooth.cip")->required();
  app.add_option(
      "--iso", opt.iso,
      "isovalue; positive side = value > isovalue (default: 0 for level sets and "
      "the field's own value for analytic fields; required otherwise); with --reconstruction auto, integer "
      "samples are built 1/64 of a level above an integer isovalue, which keeps every sample's side "
      "(docs/method.md, \"Integer samples at an integer isovalue\"), e.g. --iso 120");
  app.add_option(
         "--normals", opt.normals,
         "corner-plane normals: edge, gradient (default) or exact (analytic only), e.g. --normals exact")
      ->check(CLI::IsMember({"edge", "gradient", "exact"}));
  app.add_option(
         "--central", opt.central,
         "paper method: central coefficient zero (default) or interior (eq. 6 at "
         "a reference surface point inside the cell); fitted chooses its own. e.g. --central interior")
      ->check(CLI::IsMember({"zero", "interior"}));
  app.add_option("--method", opt.method,
                 "patch coefficients: fitted (default: no spurious sheets, see docs/method.md) "
                 "or paper (the corner I-patch paper's rules), e.g. --method paper")
      ->check(CLI::IsMember({"paper", "fitted"}));
  app.add_option(
         "--reconstruction", opt.reconstruction,
         "fitted method, gradient normals: how the reference interpolant of the samples gets its "
         "derivatives: auto (default: mask on two-valued data, central8 where the samples near the surface "
         "are smooth at the grid's scale, else monotone), monotone (limited central differences, safe next "
         "to steps as in "
         "CT), central8 (8th-order differences: far better normals on smooth, well-sampled data; "
         "overshoots at steps and on under-sampled data; docs/method.md) or mask (two-valued data such as "
         "segmentation masks: the smoothed indicator of the inside voxels, every voxel centre kept on its "
         "side; "
         "auto picks it when the samples next to the surface take two values only), e.g. --reconstruction "
         "monotone")
      ->check(CLI::IsMember({"auto", "monotone", "central8", "mask"}));
  app.add_flag(
      "--labels", opt.labels,
      "label map (integer volume): one model per non-zero label, each the surface of the voxels with "
      "that label, written to OUTPUT with -labelN before the extension (also the meshes and "
      "--stats-json); touching labels' surfaces meet (docs/method.md), e.g. --labels");
  app.add_option("--label", opt.label,
                 "label map: the surface of the voxels with label N only (written to OUTPUT as given), e.g. "
                 "--label 3");
  app.add_option("--resolution", opt.resolution,
                 "analytic fields: cells per axis over [-1,1]^3 (default 64), e.g. --resolution 128")
      ->check(CLI::Range(1, 4096));
  app.add_option("--dims", opt.dims, "raw input: grid points per axis, e.g. --dims 64,64,93");
  app.add_option("--type", opt.type,
                 "raw input: uint8|int8|uint16|int16|uint32|int32|float32|float64, e.g. --type int16");
  app.add_option("--endian", opt.endian, "raw input: little (default) or big, e.g. --endian big");
  app.add_option("--spacing", opt.spacing,
                 "raw input: world spacing sx,sy,sz (default 1,1,1), e.g. --spacing 3.2,3.2,1.5")
      ->delimiter(',');
  app.add_option(
         "--origin", opt.origin,
         "raw input: world origin x,y,z of the first sample (default 0,0,0), e.g. --origin -51.5,-47,-80.5")
      ->delimiter(',');
  app.add_option("--offset", opt.offset,
                 "raw input: bytes to skip before the first sample (default 0), e.g. --offset 352");
  app.add_option(
         "--frame", opt.frame,
         "4-D NIfTI, NRRD or MetaImage input (a series of volumes): the frame to read, counted from 0; "
         "required when the file holds more than one, e.g. --frame 3")
      ->check(CLI::Range(0, std::numeric_limits<int>::max()));
  app.add_option("--grid", opt.grid,
                 "OpenVDB input: grid name (default: the first float or double grid), e.g. --grid density");
  app.add_option(
      "--mc-mesh", opt.mcMesh,
      "also write the marching-cubes mesh of the model's cells and isovertices (the "
      "isovertices are linear crossings with --method paper, the reference's edge roots with fitted); the "
      "format follows the extension: .stl binary STL, .obj OBJ with normals, .glb binary glTF 2.0, .ply and "
      "any other binary PLY, e.g. --mc-mesh mc.ply");
  app.add_option(
      "--patch-mesh", opt.patchMesh,
      "also write a crack-free mesh of the corner-patch surface (format by extension as for --mc-mesh), "
      "e.g. --patch-mesh p.glb");
  app.add_option(
         "--space", opt.space,
         "world frame of the meshes and stats: ras, las or lps (default: the volume's own, e.g. RAS for "
         "NIfTI, LPS for DICOM and MetaImage); the model keeps the volume's, e.g. --space lps")
      ->transform(CLI::detail::to_lower)
      ->check(CLI::IsMember({"ras", "las", "lps"}));
  app.add_option(
         "--stream", opt.stream,
         "dense volume files (raw, NRRD with raw, gzip or bzip2 data, NIfTI): build the model slab by slab "
         "of z-slices, holding one slab and its halo at a time instead of the whole volume: auto (default: "
         "when the samples as doubles take 1 GiB or more, and under mpirun with 2 or more ranks, so that "
         "each "
         "rank reads only its slabs: docs/mpi.md), on (always; an error when the file or options "
         "cannot be streamed) or off (read the whole volume). The model is the same byte for byte "
         "(docs/volumes.md), e.g. --stream on")
      ->check(CLI::IsMember({"auto", "on", "off"}));
  app.add_option("--slab-cells", opt.slabCells,
                 "with --stream: cells along z each slab owns (default 0: slabs of about 64 MiB of samples "
                 "with their halo, and at least half as many cells as halo slices), "
                 "e.g. --slab-cells 8")
      ->check(CLI::Range(std::int64_t(0), std::int64_t(1) << 40));
  app.add_option("--subdiv", opt.subdiv, "patch mesh: samples per cell edge (default 4), e.g. --subdiv 8")
      ->check(CLI::Range(1, 64));
  app.add_option("--stats-json", opt.statsJson,
                 "write run statistics as JSON (counts, timings, and for --method fitted the "
                 "cells its sign checks could not satisfy and the holes at uncrossed edges it found and "
                 "closed; \"stream\": whether and in which slabs the volume was streamed; "
                 "\"peak_rss_bytes\": the peak resident memory), e.g. --stats-json stats.json");
  app.add_option("--threads", opt.threads,
                 "worker threads, 0 = all (default); the model does not depend on it, e.g. --threads 1")
      ->check(CLI::Range(0, 1024));
  app.add_flag("--skip-nonfinite", opt.skipNonFinite,
               "leave cells with NaN/Inf voxels empty instead of failing, e.g. --skip-nonfinite");
  app.add_option("--model-version", opt.modelVersion,
                 "model file format: 2 (default: compact, within 0.01 voxel of the model as built, "
                 "docs/model-format.md) or 1 (every number in full precision, ~20x larger), e.g. "
                 "--model-version 1")
      ->check(CLI::IsMember({1, 2}));
  app.add_flag("--check-storage", opt.checkStorage,
               "after writing, measure how far the surface of the model as stored lies from the model as "
               "built (on rays through every cell: distance in voxels, normal angle; docs/model-format.md), "
               "print it and add it to --stats-json under \"storage\", e.g. --check-storage");
  app.add_flag("--check-holes", opt.checkHoles,
               "after writing, count the cells of the model as stored whose patch takes the other sign than "
               "the corners somewhere on a face no neighbouring patch continues (a hole rays see through; "
               "33x33 points per face, docs/method.md \"Holes\"), print it and add it to --stats-json under "
               "\"holes\", e.g. --check-holes");
  app.add_flag("-q,--quiet", opt.quiet, "no progress bar or summary on stderr, e.g. --quiet");
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  CLI::App app{
      "extract: turn a volume into a corner-patch model (.cip).\n"
      "INPUT is a volume file (.nrrd/.nhdr, .nii/.nii.gz or .hdr/.img, .mha/.mhd, .vdb, a DICOM folder or\n"
      ".dcm, or raw with --dims/--type) or an analytic field name (sphere, torus, gyroid, marschner-lobb,\n"
      "plane) sampled over [-1,1]^3.\n\n"
      "Examples:\n"
      "  extract data/blobs.nhdr --iso 0.5 -o blobs.cip\n"
      "  extract sphere --resolution 64 --normals exact -o sphere.cip\n"
      "  extract head.raw --dims 64,64,93 --type int16 --spacing 3.2,3.2,1.5 --iso 500 -o head.cip\n"
      "  mpirun -np 4 extract tooth.nhdr --iso 120 -o tooth.cip --threads 2   (the same file; docs/mpi.md)"};
  defineOptions(app, opt);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  const double analyticPoints =
      std::filesystem::exists(opt.input) ? 0.0 : std::pow(static_cast<double>(opt.resolution) + 1, 3);
  cip::restartWithHugePages(argv, opt.input, analyticPoints);
  // Under mpirun, a rank's failure ends every rank (MPI_Abort) after it said why: no rank waits forever for
  // it, and no output is written (rank 0 writes only after every rank finished the build).
  std::unique_ptr<cip::MpiWorld> mpi;
  std::string where;
  try {
    if (cip::launchedByMpirun()) {
      mpi = cip::MpiWorld::start(&argc, &argv);
      opt.mpi = mpi.get();
      where = " (rank " + std::to_string(mpi->rank()) + " of " + std::to_string(mpi->size()) + ")";
    }
    return run(opt);
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "extract: error%s: out of memory\n", where.c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "extract: error%s: %s\n", where.c_str(), e.what());
  }
  if (mpi && mpi->size() > 1) {
    std::fflush(stderr);
    mpi->abort(1);
  }
  return 1;
}
