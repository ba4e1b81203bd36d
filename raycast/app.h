/// @file app.h
/// @brief The raycast command: options as given on the command line, and running them (load, build, render,
/// write).
#pragma once
#include <optional>
#include <string>
#include <vector>

#include "image_output.h"
#include "shading.h"

namespace cip::raycast {

struct AppOptions {
  std::string model;                                 ///< .cip model file (unless mesh is set)
  std::string mesh;                                  ///< PLY mesh file (--mesh)
  std::string output;                                ///< EXR file (-o)
  std::string png;                                   ///< optional PNG preview
  std::string compression = kDefaultExrCompression;  ///< EXR compression (--compression)
  std::string size = "800x600";                      ///< WxH
  int spp = 1;
  std::vector<double> eye, look, up;  ///< empty or 3 numbers (world)
  double fov = 35;
  bool ortho = false;
  std::string shading = "phong";
  bool shadows = false;
  std::vector<double> curvatureRange;  ///< empty or 2 numbers
  int threads = 0;
  std::string statsJson;
  std::string memoryLimit;  ///< --memory-limit: refuse above this estimated peak (empty = memory available)
  std::string space;        ///< --space: world frame of the camera and hits (empty = the model's own)
  bool quiet = false;
};

/// Parses "WxH" (e.g. 1920x1080); throws cip::Error on anything else or sizes outside 1..32768.
std::pair<int, int> parseSize(const std::string& text);

/// Whether a render is large enough for glibc's huge-page heap to pay for restarting the process
/// (restartWithHugePageHeap in core/huge_pages.h, which main calls): an input file of 64 KiB or more (its
/// decoded tables and scene take tens of MB, faulted in 4 KiB at a time otherwise) or an image of 2^20
/// samples or more. Options it cannot judge (no such file, a bad --size) count as small; runApp reports them.
bool wantsHugePageHeap(const AppOptions& options);

/// Runs the command; returns the exit status. Throws cip::Error for bad input (files, options); in that case
/// no output file has been created or changed.
int runApp(const AppOptions& options);

}  // namespace cip::raycast
