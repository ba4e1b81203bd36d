// raycast: render a corner-patch model (.cip) or a triangle mesh (PLY) to a multi-channel EXR.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>

#include "app.h"
#include "cip/core/error.h"
#include "cip/core/huge_pages.h"

int main(int argc, char** argv) {
  cip::raycast::AppOptions opt;
  CLI::App app{
      "raycast: render a corner-patch model (.cip) exactly (ray-patch roots in double precision), or a "
      "triangle mesh\n"
      "with --mesh, to an OpenEXR image with channels R,G,B,A,Z,N.x,N.y,N.z,id. See docs/raycast.md.\n\n"
      "Examples:\n"
      "  raycast sphere.cip -o sphere.exr --png sphere.png\n"
      "  raycast head.cip -o head.exr --size 1920x1080 --spp 16 --shadows --threads 8\n"
      "  raycast head.cip -o curv.exr --shading curvature --curvature-range -0.5,0.5\n"
      "  raycast --mesh head_mc.ply -o mc.exr --png mc.png --eye 3,-4,2 --look 0,0,0 --fov 30"};
  app.add_option("model", opt.model, "model file to render (.cip), e.g. sphere.cip");
  app.add_option("--mesh", opt.mesh,
                 "render this triangle mesh (PLY, ASCII or binary) instead of a model, "
                 "e.g. --mesh mc.ply");
  app.add_option("-o,--output", opt.output, "EXR image to write, e.g. -o image.exr")->required();
  app.add_option("--compression", opt.compression,
                 "EXR compression, lossless: zips:1 (default: zlib level 1, one scanline per block, the "
                 "fastest to write), zips, zip (OpenEXR's default, ~5 % smaller, several times slower to "
                 "write), zip:N / zips:N (zlib level 1-9), piz, rle or none, e.g. --compression zip");
  app.add_option("--png", opt.png, "also write an 8-bit sRGB preview, e.g. --png preview.png");
  app.add_option("--size", opt.size, "image size WxH in pixels (default 800x600), e.g. --size 1920x1080");
  app.add_option("--spp", opt.spp,
                 "samples per pixel, stratified and jittered deterministically (default 1 = the "
                 "pixel centre), e.g. --spp 16");
  app.add_option("--eye", opt.eye,
                 "camera position, world units (default: on the direction (0.6,-1,0.7) from the "
                 "model's centre, far enough to frame it), e.g. --eye 3,-4,2")
      ->delimiter(',')
      ->expected(3);
  app.add_option("--look", opt.look,
                 "point the camera looks at, world units (default: the centre of the non-empty "
                 "cells' box), e.g. --look 0,0,0")
      ->delimiter(',')
      ->expected(3);
  app.add_option("--up", opt.up, "camera up direction (default 0,0,1), e.g. --up 0,1,0")
      ->delimiter(',')
      ->expected(3);
  app.add_option("--fov", opt.fov,
                 "vertical field of view in degrees (default 35); with --ortho it sets the "
                 "window height at the look point, e.g. --fov 25")
      ->check(CLI::Range(0.01, 179.0));
  app.add_flag("--ortho", opt.ortho, "orthographic projection instead of perspective, e.g. --ortho");
  app.add_option("--shading", opt.shading,
                 "phong (default), cells, normal, depth, curvature or isophotes, "
                 "e.g. --shading curvature")
      ->check(CLI::IsMember({"phong", "cells", "normal", "depth", "curvature", "isophotes"}));
  app.add_flag("--shadows", opt.shadows,
               "the key light casts shadows (one shadow ray per sample), e.g. --shadows");
  app.add_option("--curvature-range", opt.curvatureRange,
                 "mean curvature (1/world units) at the blue and red ends "
                 "of the colour map (default: +-90th percentile of the "
                 "image, printed), e.g. --curvature-range -2,2")
      ->delimiter(',')
      ->expected(2)
      ->allow_extra_args(false);
  app.add_option("--space", opt.space,
                 "world frame of --eye/--look/--up and the image's positions and normals: ras, las or lps "
                 "(default: the model's own, e.g. RAS for NIfTI, LPS for DICOM), e.g. --space lps")
      ->transform(CLI::detail::to_lower)
      ->check(CLI::IsMember({"ras", "las", "lps"}));
  app.add_option("--memory-limit", opt.memoryLimit,
                 "refuse to render a model whose estimated peak memory exceeds this (default: the memory "
                 "available now), e.g. --memory-limit 8G")
      ->type_name("SIZE");
  app.add_option("--threads", opt.threads,
                 "worker threads, 0 = all (default); the image does not depend on it, "
                 "e.g. --threads 4")
      ->check(CLI::Range(0, 4096));
  app.add_option("--stats-json", opt.statsJson,
                 "write timings and counts as JSON, e.g. --stats-json stats.json");
  app.add_flag("-q,--quiet", opt.quiet, "no progress bar or summary on stderr, e.g. --quiet");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  if (cip::raycast::wantsHugePageHeap(opt)) cip::restartWithHugePageHeap(argv);
  try {
    return cip::raycast::runApp(opt);
  } catch (const cip::Error& e) {
    std::fprintf(stderr, "raycast: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "raycast: error: %s\n", e.what());
    return 2;
  }
}
