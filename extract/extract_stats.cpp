#include "extract_stats.h"

#include <sys/resource.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "cip/core/atomic_file.h"

namespace cip {

void writeExtractStats(const std::string& path, const ExtractStats& s, const Model& m) {
  nlohmann::json j;
  j["input"] = {{"path", s.input}, {"type", s.inputType}, {"dims", s.dims}};
  j["isovalue"] = s.isovalue;
  j["normals"] = s.normals;
  j["central"] = s.central;
  j["method"] = s.method;
  j["reconstruction"] = s.reconstruction;
  std::array<std::size_t, 5> loops{};
  for (const auto& c : m.cells) loops[std::min<std::size_t>(c.numLoops, 4)]++;
  j["model"] = {{"format_version", s.modelVersion},
                {"non_empty_cells", m.cells.size()},
                {"isovertices", m.vertices.size()},
                {"corners", m.corners.size()},
                {"loops_per_cell", {{"1", loops[1]}, {"2", loops[2]}, {"3", loops[3]}, {"4", loops[4]}}}};
  if (s.fitting) {
    j["fitting"] = {{"rounds", s.fitting->rounds},
                    {"last_round_undone", s.fitting->lastRoundUndone},
                    {"blended_isovertices", s.fitting->blendedVertices},
                    {"unresolved_cells", s.fitting->unresolvedCells.size()},
                    {"edge_holes", s.fitting->holes},
                    {"edge_holes_closed", s.fitting->holesClosed},
                    {"isovalue_raise", s.fitting->isovalueRaise}};
    if (m.reconstruction) {
      j["fitting"]["reconstruction"] = toString(*m.reconstruction);
      if (s.fitting->sampling.cells > 0) {
        // Infinite (cubic data) is written as null: JSON has no infinity.
        const double wavelength = s.fitting->sampling.wavelength;
        j["fitting"]["sampling"] = {
            {"wavelength", std::isfinite(wavelength) ? nlohmann::json(wavelength) : nlohmann::json()},
            {"sixth_to_fourth", s.fitting->sampling.sixthToFourth},
            {"cells", s.fitting->sampling.cells}};
      }
    }
  }
  if (s.storage) {
    // A non-finite figure (a hole with a vanishing gradient) is written as null: JSON has no infinity.
    auto number = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
    j["storage"] = {{"max_distance_voxels", number(s.storage->distanceVoxels.max)},
                    {"mean_distance_voxels", number(s.storage->distanceVoxels.mean)},
                    {"max_normal_degrees", number(s.storage->normalDegrees.max)},
                    {"one_sided_hits", s.storage->oneSidedHits()}};
  }
  if (s.holeCells) {
    nlohmann::json cells = nlohmann::json::array();
    for (std::size_t i = 0; i < s.holeCells->size() && i < 1000; ++i) {
      const auto& index = m.cells[(*s.holeCells)[i]].index;
      cells.push_back({index[0], index[1], index[2]});
    }
    j["holes"] = {
        {"open_face_leak_cells", s.holeCells->size()}, {"lattice", s.holeLattice}, {"cells", cells}};
  }
  {
    // Where the outputs are: the frame, the box of the non-empty cells and the full index-to-world map.
    const WorldTransform& w = s.world;
    const auto [lo, hi] = worldBounds(m, w);
    const Eigen::Matrix4d a = w.indexToWorld(m.geometry);
    nlohmann::json rows = nlohmann::json::array();
    for (int r = 0; r < 4; ++r) rows.push_back({a(r, 0), a(r, 1), a(r, 2), a(r, 3)});
    j["world"] = {{"space", toString(w.space)},
                  {"bounds", {{"lo", {lo[0], lo[1], lo[2]}}, {"hi", {hi[0], hi[1], hi[2]}}}},
                  {"index_to_world", rows}};
  }
  j["stream"] = {{"streamed", s.stream.has_value()}};
  if (s.stream) {
    j["stream"]["slabs"] = s.stream->slabs;
    j["stream"]["slab_cells"] = s.stream->slabCells;
    j["stream"]["halo_slices"] = s.stream->halo;
    j["stream"]["passes"] = s.stream->passes;
    j["stream"]["window_bytes"] = s.stream->windowBytes;
    j["stream"]["read_seconds"] = s.stream->readSeconds;
  }
  struct rusage usage {};
  if (getrusage(RUSAGE_SELF, &usage) == 0)
    j["peak_rss_bytes"] = static_cast<std::int64_t>(usage.ru_maxrss) * 1024;
  j["mpi"] = {{"ranks", s.ranks},
              {"cells_per_rank", s.cellsPerRank},
              {"exchanged_bytes", s.exchangedBytes},
              {"exchange_seconds", s.exchangeSeconds},
              {"reads_own_slabs",
               s.stream && s.ranks > 1 && s.stream->ranks.size() == static_cast<std::size_t>(s.ranks)}};
  if (s.stream) {
    nlohmann::json layers = nlohmann::json::array(), slabs = nlohmann::json::array(),
                   slices = nlohmann::json::array(), bytes = nlohmann::json::array(),
                   range = nlohmann::json::array();
    for (const RankSlices& r : s.stream->ranks) {
      layers.push_back({r.cellBegin, r.cellEnd});
      slabs.push_back(r.slabs);
      slices.push_back(r.slicesRead);
      bytes.push_back(static_cast<std::uint64_t>(r.slicesRead) * s.sliceBytes);
      range.push_back({r.firstSlice, r.endSlice});
    }
    j["mpi"]["cell_layers_per_rank"] = layers;
    j["mpi"]["slabs_per_rank"] = slabs;
    j["mpi"]["slices_read_per_rank"] = slices;
    j["mpi"]["read_bytes_per_rank"] = bytes;
    j["mpi"]["slice_range_per_rank"] = range;
  }
  j["seconds"] = s.seconds;
  j["bytes_written"] = s.bytesWritten;
  std::string text = j.dump(2) + "\n";
  writeFileAtomically(path, [&](std::FILE* f) { writeBytes(f, text.data(), text.size()); });
}

}  // namespace cip
