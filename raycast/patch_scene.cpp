#include "patch_scene.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <atomic>
#include <cmath>
#include <tuple>

#include "cip/ray/patch_bounds.h"
#include "cip/ray/ray_patch.h"
#include "cip/topology/cube_topology.h"

namespace cip::raycast {

namespace {

/// Cell boxes given to Embree are enlarged by this many cell units (plus float rounding) so that
/// single-precision traversal never culls a cell that the double-precision clip would accept.
constexpr double kBoundsPad = 1e-3;

/// Extends Embree's context with the double-precision ray (in the model's grid frame) and the closest hit so
/// far. Embree passes the
/// context pointer through to the callbacks unchanged.
struct PatchRayContext {
  RTCIntersectContext embree;  // must be first
  const PatchScene* scene = nullptr;
  Ray ray;
  double tNear = 0;
  double tFar = 0;
  double bestT = 0;  ///< closest hit so far
  std::uint32_t bestCell = 0;
  std::optional<FaceCap> bestCap;  ///< set when the closest hit closes a hole on an open face
  bool found = false;

  PatchRayContext(const PatchScene* s, const Ray& r, double near, double far)
      : scene(s), ray(r), tNear(near), tFar(far), bestT(far) {
    rtcInitIntersectContext(&embree);
  }
};

void patchBounds(const RTCBoundsFunctionArguments* args) {
  const auto* scene = static_cast<const PatchScene*>(args->geometryUserPtr);
  const Model& m = scene->model();
  const Vec3 cell = m.cellOrigin(args->primID);
  Vec3 boxLo = Vec3::Zero(), boxHi = Vec3::Ones();
  if (!zeroMaskBox(scene->zeroMask(args->primID), boxLo, boxHi)) {
    // No zero and no hole anywhere in the cell (cellHit rejects every ray): an empty box, which Embree leaves
    // out.
    RTCBounds* b = args->bounds_o;
    b->lower_x = b->lower_y = b->lower_z = 1.0f;
    b->upper_x = b->upper_y = b->upper_z = -1.0f;
    return;
  }
  const Vec3 lo = m.geometry.indexToWorld(cell + boxLo - Vec3::Constant(kBoundsPad));
  const Vec3 hi = m.geometry.indexToWorld(cell + boxHi + Vec3::Constant(kBoundsPad));
  RTCBounds* b = args->bounds_o;
  b->lower_x = roundDownToFloat(lo.x() - 1e-6 * std::abs(lo.x()));
  b->lower_y = roundDownToFloat(lo.y() - 1e-6 * std::abs(lo.y()));
  b->lower_z = roundDownToFloat(lo.z() - 1e-6 * std::abs(lo.z()));
  b->upper_x = roundUpToFloat(hi.x() + 1e-6 * std::abs(hi.x()));
  b->upper_y = roundUpToFloat(hi.y() + 1e-6 * std::abs(hi.y()));
  b->upper_z = roundUpToFloat(hi.z() + 1e-6 * std::abs(hi.z()));
}

/// A cell's answer for a ray: the first root of its patch, or a cap where the ray passes through a hole of
/// the patch surface on one of the cell's open faces (open_face_cap.h).
struct CellHit {
  double t = 0;
  std::optional<FaceCap> cap;
};

/// First root or cap of the cell on the context's double ray within [tNear, tFar] (the caller's interval,
/// not the closest hit so far: each cell's answer is then a function of the ray and the cell alone, whatever
/// order Embree visits the cells in), or nothing.
/// A cell whose padded box the ray enters after the closest hit so far is skipped: every root in it would lie
/// beyond that hit, so skipping it changes no answer.
std::optional<CellHit> cellHit(const PatchRayContext& ctx, std::uint32_t cell) {
  const PatchScene& s = *ctx.scene;
  const Vec3 origin = s.frameToLocal(ctx.ray.origin, cell);
  const Vec3 direction =
      ctx.ray.direction.cwiseQuotient(s.model().geometry.spacing);  // same t as the world ray
  double t0 = 0, t1 = 0, s0 = 0, s1 = 0;
  if (!clipRayToCell(origin, direction, ctx.tNear, ctx.tFar, t0, t1) || (ctx.found && t0 > ctx.bestT))
    return std::nullopt;
  const CornerPatch& patch = s.patch(cell);
  const std::uint64_t mask = s.zeroMask(cell);
  // An open face whose layer of sub-boxes is unmarked keeps the corners' sign (PatchScene::build): no cap.
  std::uint8_t sealed = 0;
  for (int f = 0; f < 6; ++f)
    if ((mask & zeroMaskFaceLayer(f)) == 0) sealed = static_cast<std::uint8_t>(sealed | (1u << f));
  const FaceCaps caps = openFaceCaps(
      patch, s.model().cells[cell].config, origin, direction, ctx.tNear, ctx.tFar,
      [&](int face, const Vec3& local) { return s.signAcross(cell, face, local); }, sealed);
  if (caps.entry) return CellHit{caps.entry->t, caps.entry};
  // Only the stretch from the first to the last marked sub-box can hold a root.
  std::optional<Root> root;
  if (clipRayToZeroMask(origin, direction, t0, t1, mask, s0, s1) && !(ctx.found && s0 > ctx.bestT)) {
    RootSearchOptions options;
    options.crossingsOnly = true;  // the surface separates value > isovalue from value < isovalue
    root = intersectRayPatch(patch, origin, direction, s0, s1, options);
  }
  if (root && !(caps.exit && caps.exit->t < root->t)) return CellHit{root->t, std::nullopt};
  if (caps.exit) return CellHit{caps.exit->t, caps.exit};
  return std::nullopt;
}

void patchIntersect(const RTCIntersectFunctionNArguments* args) {
  if (args->N != 1 || !args->valid[0]) return;
  auto* ctx = reinterpret_cast<PatchRayContext*>(args->context);
  auto root = cellHit(*ctx, args->primID);
  // Closest root wins; equal roots (a point on a shared face) go to the lower cell index, independent of
  // visit order.
  if (!root) return;
  if (ctx->found && !(root->t < ctx->bestT || (root->t == ctx->bestT && args->primID < ctx->bestCell)))
    return;
  ctx->bestT = root->t;
  ctx->bestCell = args->primID;
  ctx->bestCap = root->cap;
  ctx->found = true;
  auto* rh = reinterpret_cast<RTCRayHit*>(args->rayhit);
  rh->ray.tfar = roundUpToFloat(root->t);
  rh->hit.Ng_x = 0;
  rh->hit.Ng_y = 0;
  rh->hit.Ng_z = 1;
  rh->hit.u = 0;
  rh->hit.v = 0;
  rh->hit.primID = args->primID;
  rh->hit.geomID = args->geomID;
  rh->hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
}

void patchOccluded(const RTCOccludedFunctionNArguments* args) {
  if (args->N != 1 || !args->valid[0]) return;
  auto* ctx = reinterpret_cast<PatchRayContext*>(args->context);
  if (ctx->found) return;
  if (cellHit(*ctx, args->primID)) {
    ctx->found = true;
    reinterpret_cast<RTCRay*>(args->ray)->tfar = -std::numeric_limits<float>::infinity();
  }
}

/// Numbers the scenes (from 1) so that a cache entry of a destroyed scene never passes for one of a new scene
/// at the same address.
std::atomic<std::uint64_t> sceneSerial{0};

}  // namespace

const CornerPatch& PatchScene::patch(std::uint32_t cell) const {
  // Direct-mapped by cell index: a cell test and the shading of its hit, and the neighbours' sign checks,
  // ask for the same cells again and again along a row of pixels.
  struct Entry {
    std::uint64_t scene = 0;  // serial_; 0 = empty
    std::uint32_t cell = 0;
    CornerPatch patch;
  };
  constexpr std::uint32_t kEntries = 16;
  thread_local std::array<Entry, kEntries> cache;
  Entry& e = cache[cell % kEntries];
  if (e.scene != serial_ || e.cell != cell) {
    e.patch = model_.patch(cell);
    e.scene = serial_;
    e.cell = cell;
  }
  return e.patch;
}

double meanCurvature(const Vec3& g, const Mat3& h) {
  const double g2 = g.squaredNorm();
  if (!(g2 > 0)) return std::numeric_limits<double>::quiet_NaN();
  return (g2 * h.trace() - g.dot(h * g)) / (2.0 * g2 * std::sqrt(g2));
}

PatchScene::PatchScene(const Model& model, const PatchSceneOptions& options)
    : model_(model),
      serial_(++sceneSerial),
      world_(WorldTransform::of(model.geometry, options.space)),
      gradientToWorld_(world_.indexGradientToWorld(model.geometry.spacing)),
      curvature_(options.curvature),
      device_(options.threads) {
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  arena.execute([&] { build(); });
}

void PatchScene::build() {
  const Model& model = model_;
  std::tie(bounds_.lo, bounds_.hi) = worldBounds(model, world_);
  zeroMasks_.resize(model.cells.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, model.cells.size(), 256),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t c = r.begin(); c < r.end(); ++c) {
                        // Where the patch may vanish, and on each open face's layer where it may have
                        // the other sign than the face's corners: a hole the renderer closes with a cap
                        // (open_face_cap.h), which Embree must not cull.
                        const CornerPatch patch = model.patch(c);
                        std::uint64_t positive = 0;
                        std::uint64_t mask = patchZeroMask(patch, &positive);
                        const std::uint64_t negative = ~(mask | positive);
                        for (int f = 0; f < 6; ++f)
                          if (!((patch.faceMask >> f) & 1)) {
                            const bool cornersPositive =
                                (model.cells[c].config >> cube::faceVertex(f, 0)) & 1;
                            mask |= zeroMaskFaceLayer(f) & (cornersPositive ? negative : positive);
                          }
                        zeroMasks_[c] = mask;
                      }
                    });
  scene_ = rtcNewScene(device_.get());
  rtcSetSceneFlags(scene_, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_HIGH);
  if (!model.cells.empty()) {
    RTCGeometry geom = rtcNewGeometry(device_.get(), RTC_GEOMETRY_TYPE_USER);
    rtcSetGeometryUserPrimitiveCount(geom, static_cast<unsigned>(model.cells.size()));
    rtcSetGeometryUserData(geom, this);
    rtcSetGeometryBoundsFunction(geom, patchBounds, nullptr);
    rtcSetGeometryIntersectFunction(geom, patchIntersect);
    rtcSetGeometryOccludedFunction(geom, patchOccluded);
    rtcSetGeometryMask(geom, 0xFFFFFFFFu);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
  }
  rtcCommitScene(scene_);
  device_.check("building the patch scene");
}

PatchScene::~PatchScene() {
  if (scene_) rtcReleaseScene(scene_);
}

Vec3 PatchScene::frameToLocal(const Vec3& frame, std::uint32_t cell) const {
  return model_.geometry.worldToIndex(frame) - model_.cellOrigin(cell);
}

Vec3 PatchScene::worldToLocal(const Vec3& world, std::uint32_t cell) const {
  return frameToLocal(world_.toFrame(world), cell);
}

Ray PatchScene::toFrame(const Ray& ray) const {
  Ray r = ray;
  r.origin = world_.toFrame(ray.origin);
  r.direction = world_.directionToFrame(ray.direction);
  return r;
}

int PatchScene::signAcross(std::uint32_t cell, int face, const Vec3& local) const {
  const ModelCell& c = model_.cells[cell];
  const int axis = cube::faceAxis(face), step = cube::faceSide(face) == 0 ? -1 : 1;
  std::array<std::int64_t, 3> index = {c.index[0], c.index[1], c.index[2]};
  index[axis] += step;
  const std::int64_t neighbour = model_.findCell(index[0], index[1], index[2]);
  if (neighbour >= 0) {
    Vec3 there = local;
    there[axis] -= step;  // the same point in the neighbour's local coordinates
    // Not through the cache: the caller holds the cell's own cached patch, which this could evict.
    const double value = model_.patch(static_cast<std::size_t>(neighbour)).value(there);
    if (value != 0) return value > 0 ? 1 : -1;
  }
  return ((c.config >> cube::faceVertex(face, 0)) & 1) ? 1 : -1;
}

SurfaceHit PatchScene::surfaceAt(const Ray& ray, const Ray& frameRay, double t, std::uint32_t cell,
                                 const std::optional<FaceCap>& cap) const {
  SurfaceHit hit;
  hit.t = t;
  hit.position = ray.origin + t * ray.direction;
  hit.id = cell;
  hit.hasCellIndex = true;
  hit.cellIndex = model_.cells[cell].index;
  const Mat3& jt = gradientToWorld_;
  if (cap) {  // a piece of an open face closing a hole of the patch surface: flat, the face's normal
    hit.normal = (jt * capNormal(*cap)).normalized();
    if (curvature_) hit.meanCurvature = 0;
    return hit;
  }
  const Vec3 local =
      frameToLocal(frameRay.origin, cell) + t * frameRay.direction.cwiseQuotient(model_.geometry.spacing);
  const CornerPatch& p = patch(cell);
  const PatchDerivatives d = curvature_ ? p.derivatives(local) : p.valueAndGradient(local);
  // local = (frame - origin) / spacing - cell and frame = world_.toFrame(world).
  const Vec3 g = jt * d.gradient;
  const double gn = g.norm();
  hit.normal = gn > 0 ? Vec3(g / gn) : Vec3(-ray.direction);
  if (curvature_) hit.meanCurvature = meanCurvature(g, jt * d.hessian * jt.transpose());
  return hit;
}

bool PatchScene::intersect(const Ray& worldRay, double tNear, double tFar, SurfaceHit& hit) const {
  const Ray ray = toFrame(worldRay);
  PatchRayContext ctx(this, ray, tNear, tFar);
  RTCRayHit rh;
  setEmbreeRay(rh.ray, ray, tNear, tFar);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(scene_, &ctx.embree, &rh);
  if (!ctx.found) return false;
  hit = surfaceAt(worldRay, ray, ctx.bestT, ctx.bestCell, ctx.bestCap);
  return true;
}

bool PatchScene::occluded(const Ray& worldRay, double tNear, double tFar) const {
  const Ray ray = toFrame(worldRay);
  PatchRayContext ctx(this, ray, tNear, tFar);
  RTCRay r;
  setEmbreeRay(r, ray, tNear, tFar);
  rtcOccluded1(scene_, &ctx.embree, &r);
  return ctx.found;
}

}  // namespace cip::raycast
