// cip.Model, cip.load, cip.extract (as _extract, wrapped by cip/__init__.py) and cip.write_mesh.
#include <pybind11/numpy.h>
#include <pybind11/stl.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <limits>

#include "bindings.h"
#include "cancellable.h"
#include "cip/core/error.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/mesh/patch_mesh.h"
#include "cip/meshio/mesh_file.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/readers/volume_reader.h"
#include "mesh_arrays.h"
#include "volume_array.h"

namespace py = pybind11;

namespace cip::python {

namespace {

using ModelPtr = std::shared_ptr<Model>;

/// What cip.extract asks the builder for, all but the isovalue.
BuildOptions buildOptions(const std::string& method, const std::string& normals,
                          const std::string& reconstruction, int threads, bool skipNonFinite) {
  BuildOptions o;
  if (method != "fitted" && method != "paper")
    throw Error("unknown method '" + method + "' (expected fitted or paper)");
  o.method = method == "fitted" ? PatchMethod::Fitted : PatchMethod::Paper;
  o.normals = parseNormalMode(normals);
  o.reconstruction = parseReconstruction(reconstruction);
  if (o.reconstruction == Reconstruction::Central8 &&
      (o.method != PatchMethod::Fitted || o.normals != NormalMode::Gradient))
    throw Error("reconstruction " + reconstruction +
                " applies to method fitted with normals gradient (the reference of sampled data)");
  if (threads < 0) throw Error("threads must be 0 (all) or positive");
  o.threads = threads;
  o.skipNonFinite = skipNonFinite;
  return o;
}

/// Builds, naming the keyword that skips NaN cells when the input has some.
Model buildNaming(const std::function<Model()>& build) {
  try {
    return build();
  } catch (const NonFiniteSampleError& e) {
    throw Error(std::string(e.what()) + "; pass skip_nonfinite=True to leave such cells empty");
  }
}

/// The result of _extract: a list of (label, model) pairs and the data's finite range (the Python layer warns
/// when the isovalue lies outside it, as the command line does). `label` is None (one model at `level`, label
/// None), an integer (the surface of that label of a label map) or "all" (one model per non-zero label, in
/// increasing order), as `extract --label N` and `--labels`; the volume is read once.
py::tuple extract(const py::object& input, const py::object& level, const py::object& spacing,
                  const py::object& origin, const std::string& method, const std::string& normals,
                  const std::string& reconstruction, int threads, const py::object& progress,
                  bool skipNonFinite, const std::string& grid, int frame, const py::object& label) {
  BuildOptions options = buildOptions(method, normals, reconstruction, threads, skipNonFinite);
  const std::optional<double> iso =
      level.is_none() ? std::nullopt : std::optional<double>(level.cast<double>());
  const bool allLabels = py::isinstance<py::str>(label);
  if (allLabels && label.cast<std::string>() != "all")
    throw Error("label must be an integer, 'all' or None, not '" + label.cast<std::string>() + "'");
  const bool byLabel = allLabels || !label.is_none();
  if (byLabel) {
    if (iso) throw Error("give level or label, not both: a label's surface has no isovalue");
    if (options.method != PatchMethod::Fitted) throw Error("label needs method='fitted'");
    options.label = allLabels ? std::int64_t{0} : label.cast<std::int64_t>();  // 0: the apron of any label
  }
  std::optional<VolumeArray> array;
  std::string path;
  if (py::isinstance<py::str>(input)) {
    path = input.cast<std::string>();
    if (!spacing.is_none() || !origin.is_none())
      throw Error(path + ": spacing and origin come from the file; give them only with an array");
  } else {
    array.emplace(py::array::ensure(input), optionalVec3(spacing, "spacing").value_or(Vec3::Ones()),
                  optionalVec3(origin, "origin").value_or(Vec3::Zero()));
  }
  std::vector<std::pair<std::optional<std::int64_t>, std::shared_ptr<Model>>> models;
  std::pair<double, double> range;
  runCancellable(
      [&](const ReportProgress& report) {
        tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
        arena.execute([&] {
          SparseVolume volume;
          if (array) {
            volume = fromDense(array->toGrid("numpy array"));
            range = volume.range();
            options.isovalue = iso.value_or(0.5 * (range.first + range.second));
          } else {
            VolumeReadOptions read;
            read.vdbGrid = grid;
            read.frame = frame;
            read.apron = brickApron(options);
            volume = readVolume(path, read);
            range = volume.range();
            if (!iso && !volume.isLevelSet && !byLabel)
              throw Error(path + ": no default isovalue for this input; give one with level=");
            options.isovalue = iso.value_or(0.0);
          }
          std::vector<std::optional<std::int64_t>> labels{options.label};
          if (allLabels) {
            labels.clear();
            for (const std::int64_t l : labelsOf(volume)) labels.emplace_back(l);
            if (labels.empty()) throw Error("label='all' found no non-zero label");
          }
          if (byLabel) options.isovalue = 0;
          for (std::size_t k = 0; k < labels.size(); ++k) {
            // Progress over all the models, each an equal share.
            options.progress = [&, k](double f) {
              report((static_cast<double>(k) + f) / static_cast<double>(labels.size()));
            };
            options.label = labels[k];
            auto model = std::make_shared<Model>(storedModel(buildNaming(
                [&] { return buildModel(volume.geometry, volume.bricks, options, volume.description); })));
            models.emplace_back(labels[k], std::move(model));
          }
        });
      },
      progress);
  py::list out;
  for (const auto& [l, model] : models)
    out.append(py::make_tuple(l ? py::object(py::int_(*l)) : py::object(py::none()), model));
  return py::make_tuple(out, range.first, range.second);
}

/// The non-empty cell holding index point `p`, or -1: the cell whose lower corner is floor(p) or, for a point
/// on a cell face, edge or corner, the first non-empty cell among those sharing it (patches join
/// continuously).
std::int64_t cellAt(const Model& model, const Vec3& p) {
  const auto& dims = model.geometry.dims;
  std::array<std::int64_t, 3> cell{};
  int onFace = 0;  // bit a: p lies on a grid plane of axis a inside the grid, so cell[a] - 1 also holds it
  for (int a = 0; a < 3; ++a) {
    if (!(p[a] >= 0 && p[a] <= static_cast<double>(dims[a] - 1))) return -1;
    cell[a] = std::min<std::int64_t>(static_cast<std::int64_t>(p[a]), dims[a] - 2);
    if (static_cast<double>(cell[a]) == p[a] && cell[a] > 0) onFace |= 1 << a;
  }
  for (int shift = 0; shift < 8; ++shift) {
    if ((shift & ~onFace) != 0) continue;
    const std::int64_t c =
        model.findCell(cell[0] - (shift & 1), cell[1] - ((shift >> 1) & 1), cell[2] - (shift >> 2));
    if (c >= 0) return c;
  }
  return -1;
}

/// Field values and world gradients of the model's patches at world points; NaN outside non-empty cells.
py::tuple evaluate(const Model& model, const py::array& points) {
  auto p = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(points);
  if (!p || p.ndim() != 2 || p.shape(1) != 3) throw Error("points must be an (N, 3) array of numbers");
  const py::ssize_t n = p.shape(0);
  py::array_t<double> values(n), gradients({n, py::ssize_t{3}});
  const double* in = p.data();
  double* v = values.mutable_data();
  double* g = gradients.mutable_data();
  py::gil_scoped_release release;
  const GridGeometry& geo = model.geometry;
  const WorldTransform world = WorldTransform::of(geo);
  const Mat3 toWorld = world.indexGradientToWorld(geo.spacing);
  tbb::parallel_for(py::ssize_t{0}, n, [&](py::ssize_t i) {
    const Vec3 index = geo.worldToIndex(world.toFrame(Vec3(in[3 * i], in[3 * i + 1], in[3 * i + 2])));
    const std::int64_t c = cellAt(model, index);
    if (c < 0) {
      v[i] = g[3 * i] = g[3 * i + 1] = g[3 * i + 2] = std::numeric_limits<double>::quiet_NaN();
      return;
    }
    const auto cell = static_cast<std::size_t>(c);
    const PatchDerivatives d = model.patch(cell).derivatives(index - model.cellOrigin(cell));
    v[i] = d.value;
    const Vec3 gw = toWorld * d.gradient;
    for (int a = 0; a < 3; ++a) g[3 * i + a] = gw[a];
  });
  py::gil_scoped_acquire acquire;
  return py::make_tuple(values, gradients);
}

/// ((xmin, ymin, zmin), (xmax, ymax, zmax)) of the non-empty cells in world coordinates, or None.
py::object bounds(const Model& model) {
  if (model.cells.empty()) return py::none();
  const auto [lo, hi] = worldBounds(model, WorldTransform::of(model.geometry));
  return py::make_tuple(py::make_tuple(lo[0], lo[1], lo[2]), py::make_tuple(hi[0], hi[1], hi[2]));
}

py::tuple vecTuple(const Vec3& v) {
  return py::make_tuple(v[0], v[1], v[2]);
}

/// The world frame a `space=` keyword asks for: None = the model's own.
WorldTransform worldOf(const Model& model, const py::object& space) {
  return WorldTransform::of(
      model.geometry, space.is_none() ? WorldSpace::Unspecified : parseWorldSpace(space.cast<std::string>()));
}

/// The 4x4 index-to-world matrix of the model's volume (numpy, float64).
py::array_t<double> affine(const Model& model) {
  const Eigen::Matrix4d a = WorldTransform::of(model.geometry).indexToWorld(model.geometry);
  py::array_t<double> out({py::ssize_t{4}, py::ssize_t{4}});
  auto o = out.mutable_unchecked<2>();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) o(r, c) = a(r, c);
  return out;
}

}  // namespace

void bindModel(py::module_& m) {
  py::class_<Model, ModelPtr>(m, "Model", "A corner-patch model: one polynomial patch per crossed grid cell.")
      .def_property_readonly(
          "n_cells", [](const Model& x) { return x.cells.size(); },
          "number of non-empty cells (one patch each)")
      .def_property_readonly(
          "n_vertices", [](const Model& x) { return x.vertices.size(); },
          "number of isovertices (corner planes)")
      .def_property_readonly("bounds", &bounds, "world box of the non-empty cells ((lo), (hi)), or None")
      .def_property_readonly("isovalue", [](const Model& x) { return x.isovalue; })
      .def_property_readonly("method", [](const Model& x) { return std::string(toString(x.method)); })
      .def_property_readonly("normals", [](const Model& x) { return std::string(toString(x.normalMode)); })
      .def_property_readonly(
          "shape",
          [](const Model& x) {
            return py::make_tuple(x.geometry.dims[0], x.geometry.dims[1], x.geometry.dims[2]);
          },
          "grid points per axis of the source volume")
      .def_property_readonly("spacing", [](const Model& x) { return vecTuple(x.geometry.spacing); })
      .def_property_readonly("origin", [](const Model& x) { return vecTuple(x.geometry.origin); })
      .def_property_readonly(
          "affine", &affine,
          "4x4 index-to-world matrix of the volume (rotation, flips, shear, spacing, origin)")
      .def_property_readonly(
          "world_space", [](const Model& x) { return std::string(toString(x.geometry.space)); },
          "anatomical frame of the world coordinates: 'RAS', 'LAS', 'LPS' or 'unspecified'")
      .def_property_readonly("source", [](const Model& x) { return x.source; })
      .def(
          "save", [](const Model& x, const std::string& path) { return writeModel(x, path); },
          py::arg("path"), "writes the .cip file atomically; returns the bytes written")
      .def(
          "mc_mesh",
          [](const Model& x, int threads, const py::object& space) {
            const WorldTransform world = worldOf(x, space);
            TriangleMesh mesh;
            {
              py::gil_scoped_release release;
              MarchingCubesOptions o;
              o.threads = threads;
              o.recordCells = false;
              mesh = marchingCubes(x, o);
              transformMesh(mesh, world);
            }
            return meshArrays(mesh);
          },
          py::arg("threads") = 0, py::arg("space") = py::none(),
          "marching-cubes mesh of the model's cells in world coordinates (space: 'ras', 'las', 'lps' or "
          "None = the model's own): (verts, faces, normals)")
      .def(
          "patch_mesh",
          [](const Model& x, int subdiv, int threads, const py::object& space) {
            const WorldTransform world = worldOf(x, space);
            TriangleMesh mesh;
            {
              py::gil_scoped_release release;
              PatchMeshOptions o;
              o.threads = threads;
              mesh = patchMesh(x, subdiv, o);
              transformMesh(mesh, world);
            }
            return meshArrays(mesh);
          },
          py::arg("subdiv") = 4, py::arg("threads") = 0, py::arg("space") = py::none(),
          "crack-free mesh of the patch surface in world coordinates, subdiv samples per cell edge (space "
          "as for mc_mesh): (verts, faces, normals)")
      .def("evaluate", &evaluate, py::arg("points"),
           "patch values and world gradients at world points (N, 3): (values (N,), gradients (N, 3))")
      .def("__repr__", [](const Model& x) {
        return "<cip.Model " + std::to_string(x.cells.size()) + " cells, " + toString(x.method) +
               ", isovalue " + std::to_string(x.isovalue) + ">";
      });
  m.def(
      "load",
      [](const std::string& path) {
        py::gil_scoped_release release;
        return std::make_shared<Model>(readModel(path));
      },
      py::arg("path"), "reads a .cip model file");
  m.def("_extract", &extract, py::arg("input"), py::arg("level"), py::arg("spacing"), py::arg("origin"),
        py::arg("method"), py::arg("normals"), py::arg("reconstruction"), py::arg("threads"),
        py::arg("progress"), py::arg("skip_nonfinite"), py::arg("grid"), py::arg("frame"), py::arg("label"));
  m.def(
      "write_mesh",
      [](const std::string& path, const py::array& verts, const py::array& faces, const py::object& normals) {
        const TriangleMesh mesh = meshFromArrays(verts, faces, normals);
        py::gil_scoped_release release;
        return writeMesh(mesh, path);
      },
      py::arg("path"), py::arg("verts"), py::arg("faces"), py::arg("normals") = py::none(),
      "writes a mesh in the format of the file name (.ply, .stl, .obj, .glb) atomically; returns the bytes");
}

}  // namespace cip::python
