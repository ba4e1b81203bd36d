#include "app.h"

#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>

#include "cip/core/atomic_file.h"
#include "cip/core/error.h"
#include "cip/core/mapped_file.h"
#include "cip/core/progress_bar.h"
#include "cip/mesh/ply.h"
#include "cip/model/model_file.h"
#include "image_output.h"
#include "memory_plan.h"
#include "mesh_scene.h"
#include "patch_scene.h"
#include "process_clock.h"
#include "renderer.h"

namespace cip::raycast {

namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

std::optional<Vec3> vec3(const std::vector<double>& v, const char* what) {
  if (v.empty()) return std::nullopt;
  if (v.size() != 3) throw Error(std::string(what) + " needs three comma-separated numbers, e.g. 1,2,3");
  return Vec3(v[0], v[1], v[2]);
}

/// What --stats-json says of a model's memory (bytes).
struct MemoryFigures {
  std::uint64_t estimate = 0, available = 0, limit = 0, model = 0;
};

/// The model of opt.model, decoded from the file's mapping once the header has said how large it is: the
/// render's memory plan is said on stderr (unless quiet) and a plan beyond the memory available or
/// --memory-limit is refused (cip::Error) before anything large is allocated.
Model readModelWithinMemory(const AppOptions& opt, int width, int height, MemoryFigures& memory) {
  const MappedFile file(opt.model);
  const ModelTableCounts counts = modelTableCounts(file.data(), file.size(), opt.model);
  const MemoryPlan plan = planPatchRender(counts, width, height);
  memory.estimate = plan.peak();
  memory.available = availableMemory();
  memory.limit =
      opt.memoryLimit.empty() ? memory.available : parseByteSize(opt.memoryLimit, "--memory-limit");
  if (!opt.quiet)
    std::fprintf(stderr, "%s: %llu cells; needs about %s (model %s, %s %s, image %s) of %s %s\n",
                 opt.model.c_str(), static_cast<unsigned long long>(counts.cells),
                 formatBytes(plan.peak()).c_str(), formatBytes(plan.model).c_str(),
                 plan.decode > plan.scene ? "decoding" : "scene",
                 formatBytes(std::max(plan.decode, plan.scene)).c_str(), formatBytes(plan.image).c_str(),
                 memory.limit ? formatBytes(memory.limit).c_str() : "an unknown amount",
                 opt.memoryLimit.empty() ? "available" : "allowed (--memory-limit)");
  if (memory.limit && plan.peak() > memory.limit)
    throw Error(opt.model + ": rendering needs about " + formatBytes(plan.peak()) + " (model " +
                formatBytes(plan.model) + ", scene " + formatBytes(plan.scene) + ", image " +
                formatBytes(plan.image) + "), more than the " + formatBytes(memory.limit) + " " +
                (opt.memoryLimit.empty() ? "this machine has available" : "that --memory-limit allows") +
                "; free memory, render a smaller image, or pass a larger --memory-limit to try anyway");
  file.prefetch();
  Model model = parseModel(file.data(), file.size(), opt.model);
  // The decoder's buffers are free now; hand their pages back before the scene is built, so that the peak is
  // the larger of decoding and the scene over the tables, as the estimate says, not their sum.
  malloc_trim(0);
  memory.model =
      ModelTableCounts{0, model.vertices.size(), model.cells.size(), model.corners.size(), true}.tableBytes();
  return model;
}

}  // namespace

std::pair<int, int> parseSize(const std::string& text) {
  int w = 0, h = 0;
  char x = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X') || w < 1 ||
      h < 1 || w > 32768 || h > 32768)
    throw Error("--size '" + text + "' is not WxH with sizes from 1 to 32768 (e.g. 800x600)");
  return {w, h};
}

bool wantsHugePageHeap(const AppOptions& opt) {
  std::error_code error;
  const std::uintmax_t bytes = std::filesystem::file_size(opt.mesh.empty() ? opt.model : opt.mesh, error);
  if (!error && bytes >= (std::uintmax_t(64) << 10)) return true;
  try {
    const auto [width, height] = parseSize(opt.size);
    return static_cast<double>(width) * height * std::max(opt.spp, 1) >= static_cast<double>(1 << 20);
  } catch (const Error&) {
    return false;
  }
}

int runApp(const AppOptions& opt) {
  const double startupSeconds = secondsSinceProcessStart();  // libraries loaded, globals constructed
  // Validate everything cheap before the expensive work.
  const auto [width, height] = parseSize(opt.size);
  if (opt.spp < 1 || opt.spp > 4096) throw Error("--spp must be between 1 and 4096");
  if (opt.output.empty()) throw Error("no output file (-o image.exr)");
  checkExrCompression(opt.compression);
  RenderOptions render;
  render.samplesPerPixel = opt.spp;
  render.threads = opt.threads;
  render.shading.mode = parseShadingMode(opt.shading);
  render.shading.shadows = opt.shadows;
  if (!opt.curvatureRange.empty()) {
    if (opt.curvatureRange.size() != 2 || !(opt.curvatureRange[0] < opt.curvatureRange[1]))
      throw Error("--curvature-range needs two increasing numbers, e.g. -2,2");
    render.shading.curvatureRange = std::make_pair(opt.curvatureRange[0], opt.curvatureRange[1]);
  }
  CameraSettings cam;
  cam.eye = vec3(opt.eye, "--eye");
  cam.look = vec3(opt.look, "--look");
  cam.up = vec3(opt.up, "--up");
  cam.fovDegrees = opt.fov;
  cam.orthographic = opt.ortho;

  // Load and build the scene.
  const auto t0 = Clock::now();
  Model model;
  TriangleMesh mesh;
  MemoryFigures memory;
  std::unique_ptr<RenderScene> scene;
  std::string input;
  double readSeconds = 0;
  if (!opt.mesh.empty()) {
    if (!opt.model.empty()) throw Error("give either a model file or --mesh, not both");
    if (!opt.space.empty())
      throw Error("--space applies to models; a mesh is rendered in the coordinates it is written in");
    input = opt.mesh;
    mesh = readPly(opt.mesh);
    readSeconds = secondsSince(t0);
    scene = std::make_unique<MeshScene>(mesh, opt.threads);
  } else {
    if (opt.model.empty()) throw Error("no input: give a model file (.cip) or --mesh mesh.ply");
    input = opt.model;
    model = readModelWithinMemory(opt, width, height, memory);
    readSeconds = secondsSince(t0);
    PatchSceneOptions sceneOptions;
    sceneOptions.curvature = render.shading.mode == ShadingMode::Curvature;
    sceneOptions.threads = opt.threads;
    if (!opt.space.empty()) sceneOptions.space = parseWorldSpace(opt.space);
    scene = std::make_unique<PatchScene>(model, sceneOptions);
  }
  const double buildSeconds = secondsSince(t0);
  const Camera camera = makeCamera(cam, scene->bounds(), width, height);

  RenderStats stats;
  RenderImage image;
  {
    ProgressBar bar("rendering", !opt.quiet);
    render.progress = [&](double f) { bar.update(f); };
    image = cip::raycast::render(*scene, camera, render, &stats);
  }
  const auto tWrite = Clock::now();
  writeExr(image, opt.output, opt.compression, opt.threads);
  if (!opt.png.empty()) writePng(image, opt.png);
  const double writeSeconds = secondsSince(tWrite);

  const double rays = static_cast<double>(stats.primaryRays + stats.shadowRays);
  if (!opt.quiet) {
    std::fprintf(
        stderr,
        "%s: %dx%d, %d spp, %zu primitives, %lld hit pixels, scene %.3f s, render %.3f s (%.3g rays/s)\n",
        opt.output.c_str(), width, height, opt.spp, scene->primitives(),
        static_cast<long long>(stats.hitPixels), buildSeconds, stats.seconds,
        stats.seconds > 0 ? rays / stats.seconds : 0.0);
    if (render.shading.mode == ShadingMode::Curvature)
      std::fprintf(stderr, "curvature range: %g,%g (1/world units; blue = low, red = high)\n",
                   stats.curvatureLo, stats.curvatureHi);
  }
  if (!opt.statsJson.empty()) {
    nlohmann::json j;
    j["input"] = input;
    j["output"] = opt.output;
    j["size"] = {width, height};
    j["spp"] = opt.spp;
    j["threads"] = stats.threads;
    j["primitives"] = scene->primitives();
    j["shading"] = toString(render.shading.mode);
    j["shadows"] = opt.shadows;
    // scene_build = read_input + scene (kept from before the split); total: since the process started.
    j["seconds"] = {{"scene_build", buildSeconds},         {"render", stats.seconds},
                    {"startup", startupSeconds},           {"read_input", readSeconds},
                    {"scene", buildSeconds - readSeconds}, {"write_image", writeSeconds},
                    {"total", secondsSinceProcessStart()}};
    j["rays"] = {{"primary", stats.primaryRays}, {"shadow", stats.shadowRays}};
    // Bytes: the estimate said before the model was read (patch models), what the model's tables and the
    // scene took, and the process's peak resident set.
    j["memory"] = {{"scene_bytes", scene->bytes()}, {"peak_rss_bytes", peakResidentBytes()}};
    if (opt.mesh.empty())
      j["memory"].update({{"estimated_peak_bytes", memory.estimate},
                          {"available_bytes", memory.available},
                          {"limit_bytes", memory.limit},
                          {"model_bytes", memory.model}});
    j["rays_per_second"] = stats.seconds > 0 ? rays / stats.seconds : 0.0;
    j["hit_pixels"] = stats.hitPixels;
    j["camera"] = {{"eye", {camera.eye().x(), camera.eye().y(), camera.eye().z()}},
                   {"look", {camera.look().x(), camera.look().y(), camera.look().z()}},
                   {"up", {camera.up().x(), camera.up().y(), camera.up().z()}},
                   {"fov", camera.fovDegrees()},
                   {"orthographic", camera.orthographic()}};
    const Box box = scene->bounds();
    const auto* patches = dynamic_cast<const PatchScene*>(scene.get());
    j["world"] = {
        {"space", patches ? toString(patches->world().space) : "unspecified"},
        {"bounds",
         {{"lo", {box.lo.x(), box.lo.y(), box.lo.z()}}, {"hi", {box.hi.x(), box.hi.y(), box.hi.z()}}}}};
    if (render.shading.mode == ShadingMode::Curvature)
      j["curvature_range"] = {stats.curvatureLo, stats.curvatureHi};
    const std::string text = j.dump(2) + "\n";
    writeFileAtomically(opt.statsJson, [&](std::FILE* f) { writeBytes(f, text.data(), text.size()); });
  }
  return 0;
}

}  // namespace cip::raycast
