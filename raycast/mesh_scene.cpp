#include "mesh_scene.h"

#include <tbb/task_arena.h>

#include "cip/core/error.h"

namespace cip::raycast {

MeshScene::MeshScene(const TriangleMesh& mesh, int threads) : mesh_(mesh), device_(threads) {
  validateMesh(mesh, "mesh");
  bounds_.lo = Vec3::Constant(std::numeric_limits<double>::infinity());
  bounds_.hi = -bounds_.lo;
  for (const auto& tri : mesh.triangles)
    for (auto v : tri) {
      bounds_.lo = bounds_.lo.cwiseMin(mesh.positions[v]);
      bounds_.hi = bounds_.hi.cwiseMax(mesh.positions[v]);
    }
  if (mesh.triangles.empty()) bounds_.lo = bounds_.hi = Vec3::Zero();

  scene_ = rtcNewScene(device_.get());
  rtcSetSceneFlags(scene_, RTC_SCENE_FLAG_ROBUST);
  if (!mesh.triangles.empty()) {
    RTCGeometry geom = rtcNewGeometry(device_.get(), RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                          3 * sizeof(float), mesh.positions.size()));
    auto* idx = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
        geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), mesh.triangles.size()));
    if (!v || !idx) {
      rtcReleaseGeometry(geom);
      device_.check("allocating mesh buffers");
      throw Error("cannot allocate Embree buffers for the mesh");
    }
    for (std::size_t i = 0; i < mesh.positions.size(); ++i)
      for (int k = 0; k < 3; ++k) v[3 * i + k] = static_cast<float>(mesh.positions[i][k]);
    for (std::size_t i = 0; i < mesh.triangles.size(); ++i)
      for (int k = 0; k < 3; ++k) idx[3 * i + k] = mesh.triangles[i][k];
    rtcSetGeometryMask(geom, 0xFFFFFFFFu);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
  }
  tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
  arena.execute([&] { rtcCommitScene(scene_); });
  device_.check("building the mesh scene");
}

MeshScene::~MeshScene() {
  if (scene_) rtcReleaseScene(scene_);
}

bool MeshScene::intersect(const Ray& ray, double tNear, double tFar, SurfaceHit& hit) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  setEmbreeRay(rh.ray, ray, tNear, tFar);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(scene_, &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  const std::uint32_t prim = rh.hit.primID;
  const auto& tri = mesh_.triangles[prim];
  hit = SurfaceHit{};
  hit.t = rh.ray.tfar;
  hit.position = ray.origin + hit.t * ray.direction;
  Vec3 n;
  if (mesh_.hasNormals()) {
    const double u = rh.hit.u, w = rh.hit.v;
    n = (1 - u - w) * mesh_.normals[tri[0]] + u * mesh_.normals[tri[1]] + w * mesh_.normals[tri[2]];
  } else {
    const Vec3& p0 = mesh_.positions[tri[0]];
    n = (mesh_.positions[tri[1]] - p0).cross(mesh_.positions[tri[2]] - p0);
  }
  hit.normal = n.norm() > 0 ? Vec3(n.normalized()) : Vec3(-ray.direction);
  hit.id = prim < mesh_.triangleCell.size() ? mesh_.triangleCell[prim] : prim;
  return true;
}

bool MeshScene::occluded(const Ray& ray, double tNear, double tFar) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r;
  setEmbreeRay(r, ray, tNear, tFar);
  rtcOccluded1(scene_, &ctx, &r);
  return r.tfar < 0;
}

}  // namespace cip::raycast
