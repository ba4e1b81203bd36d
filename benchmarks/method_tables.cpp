#include "method_tables.h"

#include <malloc.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <regex>
#include <string>
#include <vector>

#include "cip/core/error.h"
#include "cip/measure/surface_fidelity.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/model/model_builder.h"
#include "cip/model/patch_fitting.h"
#include "cip/readers/volume_reader.h"
#include "cip/reference/tricubic_reference.h"
#include "cip/volume/analytic_field.h"

namespace cipbench {

namespace {

/// Milliseconds one call of fn takes. The heap's free memory is first returned to the system, so that every
/// build starts as in a fresh `extract` process: otherwise a build timed right after a larger one reuses its
/// pages (gyroid at N = 32: the paper construction 9.3 ms after a fitted build, 10.3 ms on its own).
double elapsedMs(const std::function<void()>& fn) {
  malloc_trim(0);
  const auto t0 = std::chrono::steady_clock::now();
  fn();
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

/// The paper and fitted models of a grid (other options as given), each built on one thread, alternately, so
/// that both see the same machine load; the best times in milliseconds. Five rounds, or for small grids as
/// many as take about a quarter of a second (at most 25): a build of a few milliseconds is otherwise decided
/// by one burst of other load on a shared machine (the torus at N = 32 in gradient mode gave 2.8x in one run
/// of five rounds and 3.0x in the next).
struct Both {
  cip::Model paper, fitted;
  double paperMs = 1e300, fittedMs = 1e300;
};
/// With --single-build each model is built once (the models are the same; only the times are not best-of).
bool gSingleBuild = false;
/// With --rows, only the cases whose name ("torus 32 gradient", "headsq.nhdr 1150", "marschner-lobb 32")
/// every expression finds.
std::vector<std::regex> gRows;

bool wanted(const std::string& caseName) {
  return std::all_of(gRows.begin(), gRows.end(),
                     [&](const std::regex& r) { return std::regex_search(caseName, r); });
}

Both buildBoth(const cip::DenseGrid& grid, cip::BuildOptions o) {
  Both both;
  o.threads = 1;
  cip::BuildOptions paper = o, fitted = o;
  paper.method = cip::PatchMethod::Paper;
  fitted.method = cip::PatchMethod::Fitted;
  int rounds = 5;
  for (int r = 0; r < rounds; ++r) {
    both.paperMs = std::min(both.paperMs, elapsedMs([&] { both.paper = cip::buildModel(grid, paper); }));
    both.fittedMs = std::min(both.fittedMs, elapsedMs([&] { both.fitted = cip::buildModel(grid, fitted); }));
    if (r == 0)
      rounds = gSingleBuild ? 1 : std::clamp(static_cast<int>(250 / (both.paperMs + both.fittedMs)), 5, 25);
  }
  return both;
}

/// Mean angle (degrees) between the reference's gradient and the true gradient at the true surface points
/// nearest the samples: how well the samples alone can know the normal.
double referenceNormalError(const std::vector<cip::SurfaceSample>& samples, const cip::ScalarField& truth,
                            const cip::ScalarField& reference, double iso) {
  double sum = 0;
  std::size_t n = 0;
  for (const auto& s : samples) {
    const cip::Vec3 p = cip::projectToSurface(truth, iso, s.world);
    const cip::Vec3 a = truth.gradient(p), b = reference.gradient(p);
    if (!(a.norm() > 0 && b.norm() > 0)) continue;
    sum += std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 57.29577951308232;
    ++n;
  }
  return n ? sum / static_cast<double>(n) : 0.0;
}

double percent(std::int64_t count, std::size_t cells) {
  return cells ? 100.0 * static_cast<double>(count) / static_cast<double>(cells) : 0.0;
}

/// Every case of the analytic table: the analytic fields but the plane at N = 32 and 64 (16 with `quick`), in
/// gradient and exact mode; fn(name, n, mode, field, grid, options) with the options of such a build.
template <class Fn>
void forEachAnalyticCase(bool quick, Fn&& fn) {
  std::vector<std::string> names = cip::analyticFieldNames();
  names.erase(std::remove(names.begin(), names.end(), "plane"), names.end());
  for (const std::string& name : names)
    for (int n : quick ? std::vector<int>{16} : std::vector<int>{32, 64})
      for (cip::NormalMode mode : {cip::NormalMode::Gradient, cip::NormalMode::Exact}) {
        if (!wanted(name + " " + std::to_string(n) + " " + cip::toString(mode))) continue;
        auto field = cip::makeAnalyticField(name);
        const cip::DenseGrid grid = cip::sampleField(*field, n, name);
        cip::BuildOptions o;
        o.isovalue = field->defaultIsovalue();
        o.normals = mode;
        o.exactField = field.get();
        fn(name, n, mode, *field, grid, o);
      }
}

/// Every case of the real-volume table that `shared` holds (the first only with `quick`): fn(file, iso,
/// grid). OpenVDB volumes are read as one brick over their active box (inactive points read as the
/// background): the model of bricks with the reference's apron is the same (VdbReader.SphereLevelSet), and
/// the reference of the measure needs one grid.
template <class Fn>
void forEachRealCase(const std::string& shared, bool quick, Fn&& fn) {
  struct Case {
    const char* file;
    double iso;
  };
  std::vector<Case> cases = {{"nucleon.nhdr", 128},  {"tooth.nhdr", 120},   {"tooth.nhdr", 200},
                             {"headsq.nhdr", 500},   {"headsq.nhdr", 1150}, {"vdb/sphere.vdb", 0},
                             {"vdb/smoke.vdb", 0.1}, {"vdb/smoke.vdb", 0.5}};
  if (quick) cases.resize(1);
  for (const Case& c : cases) {
    const std::string path = shared + "/" + c.file;
    char name[128];
    std::snprintf(name, sizeof name, "%s %g", c.file, c.iso);
    if (!wanted(name) || !std::filesystem::exists(path)) continue;
    cip::VolumeReadOptions read;
    read.brickCells = 1 << 20;
    const cip::SparseVolume volume = cip::readVolume(path, read);
    fn(c.file, c.iso, *volume.dense());
  }
}

void analyticTable(bool quick) {
  std::printf(
      "| field, N, mode | MC dist | MC facet normal | MC vertex normal "
      "| paper spurious | paper dist | paper normal "
      "| **fitted spurious** (8³/16³) | **fitted dist** | **fitted normal** (p99) "
      "| reference (auto: effective wavelength) | reference normal | time paper → fitted |\n"
      "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  forEachAnalyticCase(quick, [](const std::string& name, int n, cip::NormalMode mode,
                                const cip::AnalyticField& fieldRef, const cip::DenseGrid& grid,
                                cip::BuildOptions o) {
    const cip::AnalyticField* field = &fieldRef;
    cip::FittingStats stats;
    o.fittingStats = &stats;
    const auto [paper, fitted, tPaper, tFitted] = buildBoth(grid, o);
    const double voxel = grid.geometry.spacing.minCoeff(), iso = o.isovalue;
    const cip::TriangleMesh mesh = cip::marchingCubes(paper);
    auto mcFacet =
        cip::measureFidelity(cip::sampleMeshSurface(mesh, paper, 4, false), *field, iso, voxel, false);
    auto mcVertex =
        cip::measureFidelity(cip::sampleMeshSurface(mesh, paper, 4, true), *field, iso, voxel, false);
    auto paperF = cip::measureFidelity(cip::samplePatchSurface(paper, 4), *field, iso, voxel, false);
    const auto fittedSamples = cip::samplePatchSurface(fitted, 4);
    auto fittedF = cip::measureFidelity(fittedSamples, *field, iso, voxel, false);
    const bool sampled = mode == cip::NormalMode::Gradient;
    const cip::TricubicInterpolant interpolant(grid, stats.reconstruction);
    const std::string reference =
        sampled ? std::to_string(referenceNormalError(fittedSamples, *field, interpolant, iso)).substr(0, 5)
                : "0 (exact)";
    char kind[64] = "exact";
    if (sampled)
      std::snprintf(kind, sizeof kind, "%s (%.2f)", cip::toString(stats.reconstruction),
                    stats.sampling.wavelength);
    std::printf(
        "| %s %d %s | %.4f | %.2f | %.2f "
        "| %.1f %% | %.4f | %.2f "
        "| **%.2f / %.2f %%** | **%.4f** | **%.2f** (%.1f) "
        "| %s | %s | %.1f → %.1f ms (%.1f×) |\n",
        name.c_str(), n, cip::toString(mode), mcFacet.distanceVoxels.mean, mcFacet.normalDegrees.mean,
        mcVertex.normalDegrees.mean,
        percent(cip::countSpuriousCells(paper, *field, 8, 0.5), paper.cells.size()),
        paperF.distanceVoxels.mean, paperF.normalDegrees.mean,
        percent(cip::countSpuriousCells(fitted, *field, 8, 0.5), fitted.cells.size()),
        percent(cip::countSpuriousCells(fitted, *field, 16, 0.5), fitted.cells.size()),
        fittedF.distanceVoxels.mean, fittedF.normalDegrees.mean, fittedF.normalDegrees.p99, kind,
        reference.c_str(), tPaper, tFitted, tFitted / tPaper);
    std::fflush(stdout);
  });
}

void realTable(const std::string& shared, bool quick) {
  std::printf(
      "| volume, isovalue | cells | paper wrong-sign cells | **fitted wrong-sign cells** (8³ / 16³) "
      "| fitted dist / normal vs the interpolant | blended isovertices, unresolved cells "
      "| reference (auto: effective wavelength) | time paper → fitted |\n"
      "|---|---|---|---|---|---|---|---|\n");
  forEachRealCase(shared, quick, [](const char* file, double iso, const cip::DenseGrid& grid) {
    cip::BuildOptions o;
    o.isovalue = iso;
    cip::FittingStats stats;
    o.fittingStats = &stats;
    const auto [paper, fitted, tPaper, tFitted] = buildBoth(grid, o);
    const cip::TricubicInterpolant reference(grid, stats.reconstruction);  // the one the build chose
    const double voxel = grid.geometry.spacing.minCoeff();
    auto f = cip::measureFidelity(cip::samplePatchSurface(fitted, 4), reference, iso, voxel, false);
    const std::int64_t paperBad = cip::countSpuriousCells(paper, reference, 8, 0.5);
    std::printf(
        "| %s %g | %zu | %lld (%.1f %%) | **%lld / %lld** | %.4f / %.2f° | %zu, %zu | %s (%.2f) "
        "| %.0f → %.0f ms (%.1f×) |\n",
        file, iso, fitted.cells.size(), static_cast<long long>(paperBad),
        percent(paperBad, paper.cells.size()),
        static_cast<long long>(cip::countSpuriousCells(fitted, reference, 8, 0.5)),
        static_cast<long long>(cip::countSpuriousCells(fitted, reference, 16, 0.5)), f.distanceVoxels.mean,
        f.normalDegrees.mean, stats.blendedVertices, stats.unresolvedCells.size(),
        cip::toString(stats.reconstruction), stats.sampling.wavelength, tPaper, tFitted, tFitted / tPaper);
    std::fflush(stdout);
  });
}

/// The fitted construction with the central8 reference (gradient mode) beside the monotone one:
/// fidelity against the truth (analytic fields) or against each build's own reference (real volumes), and
/// time.
void reconstructionTable(const std::string& shared, bool quick) {
  std::printf(
      "| data, reconstruction | MC facet normal | wrong-sign cells (8³ / 16³) | dist | normal (p99) "
      "| reference normal | blended isovertices, unresolved cells | time fitted (× paper) |\n"
      "|---|---|---|---|---|---|---|---|\n");
  struct Case {
    std::string source;
    int n;  ///< analytic fields: cells per axis; volumes: 0
    double iso;
  };
  std::vector<Case> cases = {{"marschner-lobb", 32, 0}, {"marschner-lobb", 64, 0}, {"gyroid", 32, 0},
                             {"gyroid", 64, 0},         {"torus", 32, 0},          {"sphere", 32, 0},
                             {"nucleon.nhdr", 0, 128},  {"tooth.nhdr", 0, 120},    {"headsq.nhdr", 0, 1150}};
  if (quick) cases = {{"torus", 16, 0}, {"nucleon.nhdr", 0, 128}};
  for (const Case& c : cases) {
    const std::string label = c.n > 0 ? c.source + " " + std::to_string(c.n)
                                      : c.source + " " + std::to_string(static_cast<int>(c.iso));
    if (!wanted(label)) continue;
    std::unique_ptr<cip::AnalyticField> field;
    cip::DenseGrid grid;
    double iso = c.iso;
    if (c.n > 0) {
      field = cip::makeAnalyticField(c.source);
      grid = cip::sampleField(*field, c.n, c.source);
      iso = field->defaultIsovalue();
    } else {
      const std::string path = shared + "/" + c.source;
      if (!std::filesystem::exists(path)) continue;
      grid = *cip::readVolume(path).dense();
    }
    const double voxel = grid.geometry.spacing.minCoeff();
    for (cip::Reconstruction kind : {cip::Reconstruction::Monotone, cip::Reconstruction::Central8}) {
      cip::BuildOptions o;
      o.isovalue = iso;
      o.reconstruction = kind;
      cip::FittingStats stats;
      o.fittingStats = &stats;
      const auto [paper, fitted, tPaper, tFitted] = buildBoth(grid, o);
      const cip::TricubicInterpolant reference(grid, kind);
      const cip::ScalarField& truth = field ? static_cast<const cip::ScalarField&>(*field) : reference;
      const auto samples = cip::samplePatchSurface(fitted, 4);
      const auto f = cip::measureFidelity(samples, truth, iso, voxel, false);
      const auto mc = cip::measureFidelity(cip::sampleMeshSurface(cip::marchingCubes(paper), paper, 4, false),
                                           truth, iso, voxel, false);
      const std::string referenceNormal =
          field ? std::to_string(referenceNormalError(samples, *field, reference, iso)).substr(0, 5) : "–";
      std::printf("| %s, %s | %.2f | %lld / %lld | %.4f | %.2f (%.1f) | %s | %zu, %zu | %.1f ms (%.1f×) |\n",
                  label.c_str(), cip::toString(kind), mc.normalDegrees.mean,
                  static_cast<long long>(cip::countSpuriousCells(fitted, truth, 8, 0.5)),
                  static_cast<long long>(cip::countSpuriousCells(fitted, truth, 16, 0.5)),
                  f.distanceVoxels.mean, f.normalDegrees.mean, f.normalDegrees.p99, referenceNormal.c_str(),
                  stats.blendedVertices, stats.unresolvedCells.size(), tFitted, tFitted / tPaper);
      std::fflush(stdout);
    }
  }
}

/// Marschner-Lobb's normal errors by how well the grid samples its ripple where the true surface is. The
/// ripple cos(2 pi fM cos(pi r / 2)) (r: distance from the z axis) has the local frequency
/// fM (pi / 2) |sin(pi r / 2)| per unit along r; the grid of N cells on [-1, 1] carries at most N / 4 (its
/// Nyquist limit). Each sample is binned by that ratio at its projection onto the true surface; above 1 the
/// samples alias there, and no reconstruction of them knows the normal.
void aliasingTable(bool quick) {
  constexpr std::array<double, 3> kEdges{0.7, 0.85, 1.0};
  constexpr std::size_t kBins = kEdges.size() + 1;
  std::printf(
      "| Marschner–Lobb, N, normals | ripple frequency / Nyquist < 0.7 | 0.7–0.85 | 0.85–1 | > 1 (aliased) "
      "| all "
      "|\n|---|---|---|---|---|---|\n");
  auto field = cip::makeAnalyticField("marschner-lobb");
  const double iso = field->defaultIsovalue();
  for (int n : quick ? std::vector<int>{16} : std::vector<int>{32, 64}) {
    if (!wanted("marschner-lobb " + std::to_string(n))) continue;
    const cip::DenseGrid grid = cip::sampleField(*field, n, "marschner-lobb");
    const double spacing = grid.geometry.spacing.x(), nyquist = 1 / (2 * spacing);
    // The mean normal error per bin of the ripple's frequency at the sample (and the bin's share of the
    // samples), as measureFidelity measures it.
    auto row = [&](const std::string& label, const std::vector<cip::SurfaceSample>& samples, bool shares) {
      std::array<std::vector<cip::SurfaceSample>, kBins> bins;
      for (const auto& s : samples) {
        const double ratio = cip::marschnerLobbRippleFrequency(s.world) / nyquist;
        bins[static_cast<std::size_t>(std::upper_bound(kEdges.begin(), kEdges.end(), ratio) - kEdges.begin())]
            .push_back(s);
      }
      auto meanNormalError = [&](const std::vector<cip::SurfaceSample>& part) {
        return part.empty() ? 0.0
                            : cip::measureFidelity(part, *field, iso, spacing, false).normalDegrees.mean;
      };
      std::printf("| %s |", label.c_str());
      for (const auto& bin : bins) {
        std::printf(" %.2f", meanNormalError(bin));
        if (shares)
          std::printf(" (%.0f %%)",
                      100.0 * static_cast<double>(bin.size()) / static_cast<double>(samples.size()));
        std::printf(" |");
      }
      std::printf(" %.2f |\n", meanNormalError(samples));
    };
    for (cip::NormalMode mode : {cip::NormalMode::Gradient, cip::NormalMode::Exact}) {
      cip::BuildOptions o;
      o.isovalue = iso;
      o.normals = mode;
      o.exactField = field.get();
      o.threads = 1;
      cip::BuildOptions paper = o;
      paper.method = cip::PatchMethod::Paper;
      const cip::Model mcModel = cip::buildModel(grid, paper);
      const cip::TriangleMesh mesh = cip::marchingCubes(mcModel);
      const std::string prefix = std::to_string(n) + ", " + cip::toString(mode) + ": ";
      const bool sampled = mode == cip::NormalMode::Gradient;
      row(prefix + "MC facet", cip::sampleMeshSurface(mesh, mcModel, 4, false), sampled);
      if (sampled) {
        row(prefix + "MC vertex", cip::sampleMeshSurface(mesh, mcModel, 4, true), false);
        for (cip::Reconstruction kind : {cip::Reconstruction::Monotone, cip::Reconstruction::Central8}) {
          o.reconstruction = kind;
          row(prefix + "fitted, " + cip::toString(kind), cip::samplePatchSurface(cip::buildModel(grid, o), 4),
              false);
        }
      } else {
        row(prefix + "fitted", cip::samplePatchSurface(cip::buildModel(grid, o), 4), false);
      }
      std::fflush(stdout);
    }
  }
}

/// Holes: cells whose patch crosses one of its open faces (countOpenFaceLeaks), where no neighbouring patch
/// continues the surface, for both constructions on the data of the first two tables (gradient and exact
/// mode; the real volumes as the second table reads them). Marching cubes has none by construction.
void openFaceTable(const std::string& shared, bool quick) {
  std::printf(
      "| data | cells | paper: cells leaking through an open face | **fitted** |\n"
      "|---|---|---|---|\n");
  auto row = [](const std::string& name, const cip::DenseGrid& grid, cip::BuildOptions o) {
    o.method = cip::PatchMethod::Paper;
    const cip::Model paper = cip::buildModel(grid, o);
    o.method = cip::PatchMethod::Fitted;
    const cip::Model fitted = cip::buildModel(grid, o);
    const std::int64_t p = cip::countOpenFaceLeaks(paper), f = cip::countOpenFaceLeaks(fitted);
    std::printf("| %s | %zu | %lld (%.2f %%) | **%lld (%.2f %%)** |\n", name.c_str(), fitted.cells.size(),
                static_cast<long long>(p), percent(p, paper.cells.size()), static_cast<long long>(f),
                percent(f, fitted.cells.size()));
    std::fflush(stdout);
  };
  forEachAnalyticCase(quick,
                      [&](const std::string& name, int n, cip::NormalMode mode, const cip::AnalyticField&,
                          const cip::DenseGrid& grid, const cip::BuildOptions& o) {
                        row(name + " " + std::to_string(n) + " " + cip::toString(mode), grid, o);
                      });
  forEachRealCase(shared, quick, [&](const char* file, double iso, const cip::DenseGrid& grid) {
    cip::BuildOptions o;
    o.isovalue = iso;
    char name[128];
    std::snprintf(name, sizeof name, "%s %g", file, iso);
    row(name, grid, o);
  });
}

}  // namespace

const std::vector<std::string>& methodTableNames() {
  static const std::vector<std::string> names{"analytic", "real", "reconstruction", "aliasing", "open-faces"};
  return names;
}

void methodTables(const MethodTableOptions& options) {
  const std::vector<std::string>& names = methodTableNames();
  for (const std::string& t : options.tables)
    if (std::find(names.begin(), names.end(), t) == names.end())
      throw cip::Error("unknown table '" + t + "' (analytic, real, reconstruction, aliasing, open-faces)");
  gSingleBuild = options.singleBuild;
  gRows.clear();
  for (const std::string& r : options.rows) {
    try {
      gRows.emplace_back(r);
    } catch (const std::regex_error& e) {
      throw cip::Error("--rows '" + r + "' is not a regular expression: " + e.what());
    }
  }
  const std::string& shared = options.sharedData;
  const bool quick = options.quick;
  const std::vector<std::function<void()>> print{
      [&] { analyticTable(quick); }, [&] { realTable(shared, quick); },
      [&] { reconstructionTable(shared, quick); }, [&] { aliasingTable(quick); },
      [&] { openFaceTable(shared, quick); }};
  bool first = true;
  for (std::size_t t = 0; t < names.size(); ++t) {
    if (!options.tables.empty() &&
        std::find(options.tables.begin(), options.tables.end(), names[t]) == options.tables.end())
      continue;
    if (!first) std::printf("\n");
    first = false;
    print[t]();
  }
}

}  // namespace cipbench
