#include "model/ndc.h"

#include <cmath>

namespace ablenerf {

namespace {

// The NDC near plane (scene units): rays start on z = -kNdcNear.
constexpr double kNdcNear = 1.0;
// A pixel's cone radius is its neighbour distance times 2 / sqrt(12) (data/rays.h).
const double kRadiusPerStep = 2.0 / std::sqrt(12.0);

struct NdcRay {
  torch::Tensor o, d;
};

}  // namespace

torch::Tensor points_to_ndc(const torch::Tensor& x, const NdcProjection& p) {
  const auto z = x.select(-1, 2);
  return torch::stack({-p.a * x.select(-1, 0) / z, -p.b * x.select(-1, 1) / z, 1 + 2 * kNdcNear / z}, -1);
}

namespace {

NdcRay ndc_ray(const torch::Tensor& o_in, const torch::Tensor& d, const NdcProjection& p) {
  const auto dz = d.select(-1, 2);
  // Move the origin along the ray to the near plane z = -near; its image is the NDC origin.
  const auto o = o_in + (-(kNdcNear + o_in.select(-1, 2)) / dz).unsqueeze(-1) * d;
  const auto ox = o.select(-1, 0), oy = o.select(-1, 1), oz = o.select(-1, 2);
  NdcRay r;
  r.o = points_to_ndc(o, p);
  r.d = torch::stack(
      {-p.a * (d.select(-1, 0) / dz - ox / oz), -p.b * (d.select(-1, 1) / dz - oy / oz), -2 * kNdcNear / oz}, -1);
  return r;
}

}  // namespace

Rays rays_to_ndc(const Rays& rays, const NdcProjection& p) {
  const NdcRay r = ndc_ray(rays.origins, rays.directions, p);
  // The neighbouring pixels' rays: one pixel step along +x and +y of the image plane at depth
  // |d_z| (the scene frame's x and y are the cameras' right and up, give or take the capture's
  // spread). The rays carry the vertical step (radius / kRadiusPerStep, data/rays.h), used for
  // both: square pixels. In NDC a camera's rays are nearly parallel (its centre maps to infinity),
  // so the footprint is the offset between the neighbours' NDC origins, not their directions
  // (multinerf's rule).
  const auto d = rays.directions;
  const auto step = rays.radii / kRadiusPerStep * d.select(-1, 2).abs().unsqueeze(-1);
  auto offset = torch::zeros_like(rays.radii);
  for (int64_t axis = 0; axis < 2; ++axis) {
    auto e = torch::zeros_like(d);
    e.select(-1, axis).fill_(1.0);
    const NdcRay n = ndc_ray(rays.origins, d + step * e, p);
    offset = offset + 0.5 * (n.o - r.o).norm(2, -1, /*keepdim=*/true);
  }
  Rays out;
  out.origins = r.o;
  out.directions = r.d;
  out.radii = offset * kRadiusPerStep;
  return out;
}

torch::Tensor depth_from_ndc(const Rays& rays, const torch::Tensor& t_ndc) {
  // The NDC ray's origin is the image of the point on z = -near, so o'_z = 1 + 2 near / (-near) = -1,
  // and d'_z = -2 near / o_z = 2 (ndc_ray): z' = -1 + 2 t'. The map z' = 1 + 2 near / z inverts
  // to z = 2 near / (z' - 1) = -near / (1 - t'), and the scene-frame ray reaches that z at
  // t = (z - o_z) / d_z.
  const auto t = t_ndc.reshape({-1}).to(rays.origins.scalar_type());
  const auto z = -kNdcNear / (1.0 - t);
  const auto depth = (z - rays.origins.select(-1, 2)) / rays.directions.select(-1, 2);
  return depth.reshape(t_ndc.sizes()).to(t_ndc.scalar_type());
}

}  // namespace ablenerf
