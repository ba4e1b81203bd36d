#include "cip/model/slab_exchange.h"

#include <tbb/parallel_sort.h>

#include <numeric>
#include <type_traits>

#include "cip/core/error.h"

namespace cip::build {

namespace {

static_assert(std::is_trivially_copyable_v<TwoValuedSamples> && std::is_trivially_copyable_v<SamplingTerm> &&
              std::is_trivially_copyable_v<CellRef> && std::is_trivially_copyable_v<EdgeRef> &&
              std::is_trivially_copyable_v<RankSlices>);

/// Doubles per isovertex as exchanged: position, normal, weight.
constexpr std::size_t kVertexDoubles = 7;

void appendVertices(std::vector<std::uint8_t>& out, const std::vector<IsoVertex>& vertices) {
  std::vector<double> d;
  d.reserve(vertices.size() * kVertexDoubles);
  for (const IsoVertex& v : vertices)
    d.insert(d.end(),
             {v.position[0], v.position[1], v.position[2], v.normal[0], v.normal[1], v.normal[2], v.weight});
  appendVector(out, d);
}

void readVertices(ByteReader& in, std::vector<IsoVertex>& out) {
  const std::vector<double> d = in.vector<double>();
  if (d.size() % kVertexDoubles != 0) throw Error("a rank sent a partial isovertex");
  for (std::size_t n = 0; n < d.size(); n += kVertexDoubles) {
    IsoVertex v;
    v.position = Vec3(d[n], d[n + 1], d[n + 2]);
    v.normal = Vec3(d[n + 3], d[n + 4], d[n + 5]);
    v.weight = d[n + 6];
    out.push_back(v);
  }
}

template <class T>
void appendTo(std::vector<T>& out, const std::vector<T>& more) {
  out.insert(out.end(), more.begin(), more.end());
}

}  // namespace

void gatherFirstPass(const Collective& ranks, const FirstPassRecord& mine, TwoValuedVerdict& verdict,
                     SamplingEstimator& estimator) {
  std::vector<std::uint8_t> bytes;
  appendVector(bytes, mine.twoValued);
  appendVector(bytes, mine.terms);
  appendBytes(bytes, &mine.cells, 1);
  for (const std::vector<std::uint8_t>& theirs : ranks.allgather(bytes)) {
    ByteReader in(theirs);
    for (const TwoValuedSamples& t : in.vector<TwoValuedSamples>()) verdict.add(t);
    const std::vector<SamplingTerm> terms = in.vector<SamplingTerm>();
    estimator.addTerms(terms.data(), terms.size(), in.value<std::int64_t>());
  }
}

std::vector<RankSlices> gatherHarvests(const Collective& ranks, SlabHarvest& harvest,
                                       const std::vector<std::int64_t>& firstSlab,
                                       const RankSlices& reading) {
  const int me = ranks.rank();
  std::vector<std::uint8_t> bytes;
  appendBytes(bytes, &reading, 1);
  appendVector(bytes, harvest.cells);
  appendVector(bytes, harvest.edges);
  appendVertices(bytes, harvest.vertices);
  if (harvest.reference.sampled)
    for (std::int64_t s = firstSlab[static_cast<std::size_t>(me)];
         s < firstSlab[static_cast<std::size_t>(me) + 1]; ++s)
      harvest.reference.tables[static_cast<std::size_t>(s)].appendTo(bytes);
  const std::vector<std::vector<std::uint8_t>> all = ranks.allgather(bytes);
  bytes = std::vector<std::uint8_t>();
  SlabHarvest joined;
  joined.reference = std::move(harvest.reference);
  std::vector<RankSlices> readings;
  for (int r = 0; r < ranks.size(); ++r) {
    if (r == me) {  // no need to read back its own
      readings.push_back(reading);
      appendTo(joined.cells, harvest.cells);
      appendTo(joined.edges, harvest.edges);
      appendTo(joined.vertices, harvest.vertices);
      continue;
    }
    ByteReader in(all[static_cast<std::size_t>(r)]);
    readings.push_back(in.value<RankSlices>());
    appendTo(joined.cells, in.vector<CellRef>());
    appendTo(joined.edges, in.vector<EdgeRef>());
    readVertices(in, joined.vertices);
    if (joined.reference.sampled)
      for (std::int64_t s = firstSlab[static_cast<std::size_t>(r)];
           s < firstSlab[static_cast<std::size_t>(r) + 1]; ++s)
        joined.reference.tables[static_cast<std::size_t>(s)] = PointHermiteTable::readFrom(in);
    if (!in.atEnd() || joined.edges.size() != joined.vertices.size())
      throw Error("rank " + std::to_string(r) + " sent a harvest that does not add up");
  }
  harvest = std::move(joined);
  return readings;
}

void sortEdges(SlabHarvest& h) {
  std::vector<std::uint32_t> order(h.edges.size());
  std::iota(order.begin(), order.end(), 0u);
  tbb::parallel_sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
    return h.edges[a].key != h.edges[b].key ? h.edges[a].key < h.edges[b].key : a < b;
  });
  std::vector<EdgeRef> edges;
  std::vector<IsoVertex> vertices;
  edges.reserve(order.size());
  vertices.reserve(order.size());
  for (std::size_t n = 0; n < order.size(); ++n) {
    if (n > 0 && h.edges[order[n]].key == h.edges[order[n - 1]].key) continue;  // the lower slab's is kept
    edges.push_back(h.edges[order[n]]);
    vertices.push_back(h.vertices[order[n]]);
  }
  h.edges = std::move(edges);
  h.vertices = std::move(vertices);
}

}  // namespace cip::build
