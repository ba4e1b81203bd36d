// cip_bench: the measurements behind benchmarks/results/report.md, printed as CSV rows. Every figure of a row
// comes from runs made side by side in the same invocation. Driven by benchmarks/run.py; usable alone:
//   cip_bench extraction --csv extraction.csv [--quick] [--shared-data ../shared/data]
//   cip_bench fidelity   --csv fidelity.csv   [--quick]
//   cip_bench method     [--quick] [--shared-data ../shared/data] [--table NAME]... [--single-build]
//                        [--rows REGEX]...
//                        (the tables of docs/method.md)
//   cip_bench displacement --model FULL.cip --stored STORED.cip [--json out.json] [--rays-per-axis K]
//                        (how far the stored model's surface lies from the full one's: model_displacement.h)
//   cip_bench mesh-codecs --ply MC.ply [--json OUT] [--reps N] [--min-seconds S]
//                        (the marching-cubes mesh through meshoptimizer and zstd: bytes, encode and decode
//                        times)
//   cip_bench model-io   --model M.cip --ply MC.ply [--json OUT] [--reps N] [--min-seconds S]
//                        (model read/parse/serialize/write and PLY read/parse/write, 1 thread and all, MB/s
//                        of PLY)
#include <malloc.h>
#include <tbb/info.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <regex>

#include "cip/measure/continuity_check.h"
#include "cip/measure/model_displacement.h"
#include "cip/measure/surface_fidelity.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/mesh/ply.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/readers/volume_reader.h"
#include "cip/volume/analytic_field.h"
#include "method_tables.h"
#include "openvdb_peer.h"
#include "size_peers.h"

namespace {

using Clock = std::chrono::steady_clock;

/// Best wall times of five runs of each of `fns`, run in turn (a, b, a, b, ...) so that all see the same
/// machine load. Other guests' load on the shared machine only adds time, so the best run is the measure: a
/// single run, as long ones once had, let one burst decide a ratio (gyroid at N = 256 on two threads:
/// fitted/paper 3.09x in one run, 2.41x in the next; the sphere at N = 64 on one thread 3.09x in one run of
/// medians of three, 2.4x in the others). Before each run, `release[k]` (if given) frees what the previous
/// run of fns[k] kept, and the heap's free memory is returned to the system (malloc_trim), as in a fresh
/// process, so that a run does not reuse the pages of the one timed before it.
std::vector<double> timeInTurn(const std::vector<std::function<void()>>& fns,
                               const std::vector<std::function<void()>>& release = {}) {
  std::vector<std::vector<double>> t(fns.size());
  for (int r = 0; r < 5; ++r)
    for (std::size_t k = 0; k < fns.size(); ++k) {
      if (k < release.size()) release[k]();
      malloc_trim(0);
      auto t0 = Clock::now();
      fns[k]();
      t[k].push_back(std::chrono::duration<double>(Clock::now() - t0).count());
    }
  std::vector<double> best;
  for (const auto& runs : t) best.push_back(*std::min_element(runs.begin(), runs.end()));
  return best;
}
double timeIt(const std::function<void()>& fn) {
  return timeInTurn({fn})[0];
}

class Csv {
 public:
  Csv(const std::string& path, const std::string& header) : out_(path) {
    if (!out_) throw std::runtime_error("cannot write " + path);
    out_ << header << "\n";
  }
  template <class... T>
  void row(const T&... v) {
    std::ostringstream s;
    s.precision(6);
    bool first = true;
    ((s << (first ? "" : ",") << v, first = false), ...);
    out_ << s.str() << "\n";
    out_.flush();
    std::fprintf(stderr, "  %s\n", s.str().c_str());
  }

 private:
  std::ofstream out_;
};

std::size_t plyBytes(const cip::TriangleMesh& mesh) {
  auto path = std::filesystem::temp_directory_path() / "cip_bench_mesh.ply";
  std::size_t n = cip::writePly(mesh, path.string());
  std::filesystem::remove(path);
  return n;
}

struct Case {
  std::string name;    // e.g. sphere-128, tooth
  std::string source;  // analytic | file path
  int resolution = 0;  // analytic only
  double iso = 0;
  std::size_t inputBytes = 0;
};

/// A real MRI-sized volume: the Colin 27 T1 brain template (181x217x181, 1 mm, uint8) of Debian's
/// mricron-data.
const char* kMri = "/usr/share/mricron/templates/ch2.nii.gz";

void extraction(const std::string& csvPath, bool quick, const std::string& shared, const std::string& only) {
  Csv csv(csvPath,
          "case,points,cells,method,threads,seconds,mcells_per_s,output_count,output_bytes,input_bytes");
  std::vector<Case> cases;
  // The three volumes of the speed targets (docs/performance.md) first, then smaller ones for the per-cell
  // plot.
  if (quick) {
    for (const char* f : {"sphere", "gyroid"}) cases.push_back({std::string(f) + "-32", f, 32, 0.0, 0});
  } else {
    cases.push_back({"sphere-256", "sphere", 256, 0.0, 0});
    cases.push_back({"gyroid-192", "gyroid", 192, 0.0, 0});
    if (std::filesystem::exists(kMri)) cases.push_back({"mri-colin27", kMri, 0, 60.0, 0});
    for (const char* f : {"sphere", "torus", "gyroid"})
      for (int n : {64, 128}) cases.push_back({std::string(f) + "-" + std::to_string(n), f, n, 0.0, 0});
  }
  if (std::filesystem::exists(shared)) {
    std::vector<std::pair<std::string, double>> files = {
        {"nucleon.nhdr", 128}, {"tooth.nhdr", 120}, {"headsq.nhdr", 500}};
    if (quick) files.resize(1);
    for (auto& [file, iso] : files) cases.push_back({file, shared + "/" + file, 0, iso, 0});
  }
  if (!only.empty()) {
    const std::regex re(only);
    cases.erase(std::remove_if(cases.begin(), cases.end(),
                               [&](const Case& c) { return !std::regex_search(c.name, re); }),
                cases.end());
  }
  const int allThreads = tbb::info::default_concurrency();
  {
    // Untimed builds of a small field first, so that the first case does not pay for the process's warm-up
    // (lazy binding, the thread pool, the first growth of the heap).
    const cip::DenseGrid warm = cip::sampleField(*cip::makeAnalyticField("sphere"), 16, "sphere");
    for (cip::PatchMethod method : {cip::PatchMethod::Fitted, cip::PatchMethod::Paper}) {
      cip::BuildOptions o;
      o.method = method;
      cip::buildModel(warm, o);
    }
  }
  for (Case& c : cases) {
    std::fprintf(stderr, "extraction: %s\n", c.name.c_str());
    cip::DenseGrid grid;
    if (c.resolution > 0) {
      auto field = cip::makeAnalyticField(c.source);
      grid = cip::sampleField(*field, c.resolution, c.source);
      c.inputBytes = grid.values.size() * sizeof(float);  // as a float32 volume
    } else {
      cip::SparseVolume v = cip::readVolume(c.source);
      grid = std::move(*const_cast<cip::DenseGrid*>(v.dense()));
      c.inputBytes = cip::volumeFileBytes(c.source);
    }
    const auto& d = grid.geometry.dims;
    const double cells = static_cast<double>((d[0] - 1) * (d[1] - 1) * (d[2] - 1));
    cipbench::OpenVdbPeer peer(grid);
    for (int threads : {1, allThreads}) {
      cip::BuildOptions o;
      o.isovalue = c.iso;
      o.threads = threads;
      // The two constructions in turn: their ratio is the figure docs/method.md holds to 3x.
      const std::array<cip::PatchMethod, 2> methods{cip::PatchMethod::Fitted, cip::PatchMethod::Paper};
      std::array<cip::Model, 2> models;
      std::vector<std::function<void()>> builds, release;
      for (std::size_t k = 0; k < methods.size(); ++k) {
        builds.push_back([&, k] {
          cip::BuildOptions mo = o;
          mo.method = methods[k];
          models[k] = cip::buildModel(grid, mo);
        });
        release.push_back([&, k] { models[k] = cip::Model(); });
      }
      const std::vector<double> tModel = timeInTurn(builds, release);
      for (std::size_t k = 0; k < methods.size(); ++k) {
        const std::size_t modelBytes = cip::serializeModel(models[k]).size();
        csv.row(c.name, grid.values.size(), cells, std::string("cip-patches-") + cip::toString(methods[k]),
                threads, tModel[k], cells / tModel[k] * 1e-6, models[k].cells.size(), modelBytes,
                c.inputBytes);
      }
      o.method = cip::PatchMethod::Paper;
      cip::TriangleMesh mc;
      o.fitCoefficients = false;
      double tMc = timeIt([&] {
        cip::Model skeleton = cip::buildModel(grid, o);
        cip::MarchingCubesOptions mo;
        mo.threads = threads;
        mo.recordCells = false;
        mc = cip::marchingCubes(skeleton, mo);
      });
      csv.row(c.name, grid.values.size(), cells, "cip-marching-cubes", threads, tMc, cells / tMc * 1e-6,
              mc.triangleCount(), plyBytes(mc), c.inputBytes);
      std::size_t polys = 0;
      double tVdb = timeIt([&] { polys = peer.mesh(c.iso, threads); });
      csv.row(c.name, grid.values.size(), cells, "openvdb-volumeToMesh", threads, tVdb, cells / tVdb * 1e-6,
              polys, 0, c.inputBytes);
    }
  }
}

struct Variant {
  std::string name;
  cip::NormalMode normals;
};

void fidelity(const std::string& csvPath, bool quick) {
  Csv csv(
      csvPath,
      "field,N,method,cells,samples,dist_mean,dist_p99,dist_max,normal_mean,normal_p99,curv_mean,curv_p99,"
      "spurious_cells,continuity_max_gap,continuity_max_angle_deg");
  const std::vector<int> sizes = quick ? std::vector<int>{16} : std::vector<int>{16, 32, 64, 128};
  for (const char* name : {"sphere", "torus", "gyroid", "marschner-lobb"}) {
    auto field = cip::makeAnalyticField(name);
    for (int n : sizes) {
      std::fprintf(stderr, "fidelity: %s N=%d\n", name, n);
      cip::DenseGrid grid = cip::sampleField(*field, n, name);
      const double voxel = grid.geometry.spacing.minCoeff();
      const int lines = n >= 128 ? 2 : n >= 64 ? 3 : 4;
      const double iso = field->defaultIsovalue();
      auto report = [&](const std::string& method, const cip::Model& m,
                        const std::vector<cip::SurfaceSample>& s, bool patches) {
        cip::FidelityMeasures f = cip::measureFidelity(s, *field, iso, voxel, patches);
        std::int64_t spurious = patches ? cip::countSpuriousCells(m, *field, n >= 128 ? 4 : 8, 0.5) : 0;
        cip::ContinuityStats cont;
        if (patches) cont = cip::measureContinuity(m, n >= 64 ? 6 : 12);
        csv.row(name, n, method, m.cells.size(), f.distanceVoxels.count, f.distanceVoxels.mean,
                f.distanceVoxels.p99, f.distanceVoxels.max, f.normalDegrees.mean, f.normalDegrees.p99,
                patches ? f.curvatureError.mean : 0.0, patches ? f.curvatureError.p99 : 0.0,
                patches ? spurious : -1, patches ? cont.maxGap : -1.0,
                patches ? cont.maxAngle * 57.29577951308232 : -1.0);
      };
      for (cip::PatchMethod method : {cip::PatchMethod::Fitted, cip::PatchMethod::Paper})
        for (cip::NormalMode mode :
             {cip::NormalMode::Edge, cip::NormalMode::Gradient, cip::NormalMode::Exact}) {
          cip::BuildOptions o;
          o.isovalue = iso;
          o.normals = mode;
          o.method = method;
          o.exactField = field.get();
          // The model as its file stores it (format 2): the surface users get.
          cip::Model m = cip::storedModel(cip::buildModel(grid, o));
          report(std::string("patch-") + toString(m.method) + "-" + cip::toString(mode), m,
                 cip::samplePatchSurface(m, lines), true);
        }
      // The fitted construction on each reference of the samples (tricubic_reference.h); the rows above
      // have the one Reconstruction::Auto chose.
      for (cip::Reconstruction kind : {cip::Reconstruction::Monotone, cip::Reconstruction::Central8}) {
        cip::BuildOptions o;
        o.isovalue = iso;
        o.reconstruction = kind;
        cip::Model m = cip::storedModel(cip::buildModel(grid, o));
        report(std::string("patch-fitted-gradient-") + cip::toString(kind), m,
               cip::samplePatchSurface(m, lines), true);
      }
      // Marching cubes on linearly interpolated isovertices with central-difference normals (the usual
      // method: the paper construction's isovertices; the fitted one's lie on its reference), and on exact
      // ones.
      for (cip::NormalMode mode : {cip::NormalMode::Gradient, cip::NormalMode::Exact}) {
        cip::BuildOptions o;
        o.isovalue = iso;
        o.normals = mode;
        o.method = cip::PatchMethod::Paper;
        o.exactField = field.get();
        o.fitCoefficients = false;
        cip::Model m = cip::buildModel(grid, o);
        cip::TriangleMesh mesh = cip::marchingCubes(m);
        std::string base = mode == cip::NormalMode::Exact ? "mc-exactvertices" : "mc";
        report(base + "-facet", m, cip::sampleMeshSurface(mesh, m, lines, false), false);
        report(base + "-vertexnormals-" + cip::toString(mode), m,
               cip::sampleMeshSurface(mesh, m, lines, true), false);
      }
    }
  }
}

nlohmann::json summaryJson(const cip::ErrorSummary& s) {
  // Non-finite figures (a hole with a vanishing gradient) are written as null: JSON has no infinity.
  auto number = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
  return {{"count", s.count}, {"mean", number(s.mean)}, {"p99", number(s.p99)}, {"max", number(s.max)}};
}

/// Measures a stored model against the full-precision one it was made from (a codec's quantisation: the
/// figures the storage requirement bounds, max distance 0.01 voxel), printed and written as JSON.
void displacement(const std::string& fullPath, const std::string& storedPath, const std::string& jsonPath,
                  int raysPerAxis) {
  const cip::Model full = cip::readModel(fullPath);
  const cip::Model stored = cip::readModel(storedPath);
  cip::DisplacementOptions o;
  o.raysPerAxis = raysPerAxis;
  const auto t0 = Clock::now();
  const cip::ModelDisplacement d = cip::measureModelDisplacement(full, stored, o);
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  std::fprintf(stderr,
               "%s vs %s: %lld cells, %lld rays in %.2f s; distance max %.3g mean %.3g p99 %.3g voxel, "
               "normal max %.3g mean %.3g deg, depth max %.3g voxel, %lld one-sided hits (max %.3g voxel), "
               "worst cell %u %u %u\n",
               storedPath.c_str(), fullPath.c_str(), static_cast<long long>(d.cellsCompared),
               static_cast<long long>(d.rays), seconds, d.distanceVoxels.max, d.distanceVoxels.mean,
               d.distanceVoxels.p99, d.normalDegrees.max, d.normalDegrees.mean, d.depthVoxels.max,
               static_cast<long long>(d.oneSidedHits()), d.oneSidedDistanceVoxels.max, d.worstCell[0],
               d.worstCell[1], d.worstCell[2]);
  if (d.cellsOnlyInReference + d.cellsOnlyInStored > 0)
    std::fprintf(stderr, "cells only in the full model: %lld, only in the stored one: %lld\n",
                 static_cast<long long>(d.cellsOnlyInReference), static_cast<long long>(d.cellsOnlyInStored));
  if (jsonPath.empty()) return;
  nlohmann::json j;
  j["model"] = fullPath;
  j["stored"] = storedPath;
  j["rays_per_axis"] = raysPerAxis;
  j["seconds"] = seconds;
  j["same_geometry"] = d.sameGeometry;
  j["cells"] = {{"compared", d.cellsCompared},
                {"only_in_model", d.cellsOnlyInReference},
                {"only_in_stored", d.cellsOnlyInStored}};
  j["rays"] = {{"cast", d.rays},
               {"both_hit", d.bothHit},
               {"model_only_hits", d.referenceOnlyHits},
               {"stored_only_hits", d.storedOnlyHits},
               {"first_order_estimates", d.firstOrderEstimates}};
  j["distance_voxels"] = summaryJson(d.distanceVoxels);
  j["normal_degrees"] = summaryJson(d.normalDegrees);
  j["depth_voxels"] = summaryJson(d.depthVoxels);
  j["ray_normal_degrees"] = summaryJson(d.rayNormalDegrees);
  j["one_sided_distance_voxels"] = summaryJson(d.oneSidedDistanceVoxels);
  j["worst_cell"] = d.worstCell;
  std::ofstream out(jsonPath);
  if (!(out << j.dump(2) << "\n")) throw std::runtime_error("cannot write " + jsonPath);
}

}  // namespace

/// Bytes per stream of a format 2 file and per patch cell.
void modelStreams(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  const std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), {});
  const cip::Model m = cip::parseModel(bytes.data(), bytes.size(), path);
  nlohmann::json j;
  j["file_bytes"] = bytes.size();
  j["cells"] = m.cells.size();
  j["bytes_per_cell"] =
      static_cast<double>(bytes.size()) / static_cast<double>(std::max<std::size_t>(1, m.cells.size()));
  for (const auto& [name, n] : cip::modelFileV2Streams(bytes)) j["streams"][name] = n;
  std::printf("%s\n", j.dump(2).c_str());
}

int main(int argc, char** argv) {
  CLI::App app{"cip_bench: side-by-side extraction and fidelity measurements (CSV)"};
  app.require_subcommand(1);
  std::string csv, shared = "../shared/data";
  bool quick = false;
  auto* ex = app.add_subcommand("extraction",
                                "extraction time and output size: cip patches vs marching cubes vs OpenVDB");
  ex->add_option("--csv", csv, "output CSV")->required();
  ex->add_option("--shared-data", shared, "folder with the real volumes");
  ex->add_flag("--quick", quick, "small sizes only");
  std::string cases;
  ex->add_option("--cases", cases,
                 "only the cases whose name matches this regular expression, e.g. 'sphere-256'");
  auto* fi = app.add_subcommand("fidelity", "distance, normal and curvature errors against analytic fields");
  fi->add_option("--csv", csv, "output CSV")->required();
  fi->add_flag("--quick", quick, "small sizes only");
  auto* me = app.add_subcommand("method", "the measured tables of docs/method.md (Markdown on stdout)");
  cipbench::MethodTableOptions method;
  me->add_option("--shared-data", method.sharedData, "folder with the real volumes");
  me->add_flag("--quick", method.quick, "N = 16 and the nucleon only");
  me->add_option("--table", method.tables,
                 "only this table (repeatable): analytic, real, reconstruction, aliasing, open-faces");
  me->add_flag("--single-build", method.singleBuild,
               "build each model once (same figures; the times are of one build, not the best of several)");
  me->add_option("--rows", method.rows,
                 "only the cases whose name matches this regular expression (repeatable: all of them), "
                 "e.g. --rows '32|nucleon'");
  auto* st =
      app.add_subcommand("model-streams", "where the bytes of a format 2 model file go (JSON on stdout)");
  std::string streamsModel;
  st->add_option("--model", streamsModel, "the .cip file (format 2)")->required();
  auto* di = app.add_subcommand(
      "displacement", "how far a stored model's surface lies from the full-precision model's (codec tuning)");
  std::string fullModel, storedModel, json;
  int raysPerAxis = cip::DisplacementOptions().raysPerAxis;
  di->add_option("--model", fullModel, "the full-precision model (.cip)")->required();
  di->add_option("--stored", storedModel, "the same model as stored (.cip)")->required();
  di->add_option("--json", json, "write the figures as JSON");
  di->add_option("--rays-per-axis", raysPerAxis,
                 "k: k x k rays per direction and cell, 7 directions (default 4)")
      ->check(CLI::Range(1, 64));
  auto* mc = app.add_subcommand(
      "mesh-codecs",
      "the marching-cubes mesh encoded with meshoptimizer (and zstd on top): bytes and times (JSON)");
  cipbench::MeshCodecOptions codecs;
  mc->add_option("--ply", codecs.ply, "the mesh, e.g. as written by extract --mc-mesh mc.ply")->required();
  mc->add_option("--json", codecs.json, "also write the JSON to this file");
  mc->add_option("--reps", codecs.reps, "timed runs of each encode and decode (the best counts)")
      ->check(CLI::PositiveNumber);
  mc->add_option("--min-seconds", codecs.minSeconds,
                 "more runs while one operation's runs took less than this altogether");
  mc->add_option("--zstd-level", codecs.zstdLevel, "zstd level on top of meshoptimizer")
      ->check(CLI::Range(1, 22));
  auto* io =
      app.add_subcommand("model-io",
                         "model read/parse/serialize/write against PLY read/parse/write of the mesh of the "
                         "same model, 1 thread and all, in MB/s of the PLY (JSON)");
  cipbench::ModelIoOptions modelIo;
  io->add_option("--model", modelIo.model, "the .cip file")->required();
  io->add_option("--ply", modelIo.ply, "its marching-cubes mesh (extract --mc-mesh)")->required();
  io->add_option("--json", modelIo.json, "also write the JSON to this file");
  io->add_option("--reps", modelIo.reps, "timed runs of each operation (the best counts)")
      ->check(CLI::PositiveNumber);
  io->add_option("--min-seconds", modelIo.minSeconds,
                 "more runs while one operation's runs took less than this altogether");
  CLI11_PARSE(app, argc, argv);
  try {
    if (*ex) extraction(csv, quick, shared, cases);
    if (*fi) fidelity(csv, quick);
    if (*me) cipbench::methodTables(method);
    if (*di) displacement(fullModel, storedModel, json, raysPerAxis);
    if (*st) modelStreams(streamsModel);
    if (*mc) cipbench::meshCodecs(codecs);
    if (*io) cipbench::modelIo(modelIo);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cip_bench: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
