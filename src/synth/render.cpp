#include "synth/render.h"

#include <algorithm>
#include <cmath>
#include <thread>

namespace ablenerf::synth {

namespace {

// Renders rows first_row, first_row + stride, ... into img.
void render_rows(const SceneTracer& scene, const Camera& cam, int first_row, int stride, bool environment_background,
                 const Vec3& gain, const Distractor* distractor, ViewImage& img) {
  const Sphere ball{"distractor", MaterialKind::Diffuse, distractor ? distractor->centre : Vec3{},
                    distractor ? distractor->radius : 0.0};
  constexpr int n = kSubsamplesPerAxis;
  constexpr double inv_samples = 1.0 / (n * n);
  for (int j = first_row; j < img.height; j += stride) {
    for (int i = 0; i < img.width; ++i) {
      Vec3 sum;
      int hits = 0;
      bool seen_ball = false;
      for (int sy = 0; sy < n; ++sy)
        for (int sx = 0; sx < n; ++sx) {
          const Ray r = camera_ray(cam, i + (sx + 0.5) / n, j + (sy + 0.5) / n);
          const Hit hit = scene.intersect(r, 0.0);
          const bool on_ball = distractor && intersect_sphere(ball, r, 0.0) < hit.t;
          if (on_ball) seen_ball = true;
          if (!on_ball && !environment_background && !hit.hit()) continue;
          // Clamp each sub-sample before averaging: the film saturates, and an unclamped sun
          // highlight would otherwise bleed across the whole pixel.
          const Vec3 c = (on_ball ? distractor_colour() : scene.trace(r, 0)) * gain;
          sum += Vec3{std::clamp(c.x, 0.0, 1.0), std::clamp(c.y, 0.0, 1.0), std::clamp(c.z, 0.0, 1.0)};
          ++hits;
        }
      const size_t px = static_cast<size_t>(j) * img.width + i;
      float* out = &img.rgba[px * 4];
      if (hits > 0) {
        const Vec3 mean = sum / hits;  // straight (non-premultiplied) colour
        out[0] = static_cast<float>(linear_to_srgb(mean.x));
        out[1] = static_cast<float>(linear_to_srgb(mean.y));
        out[2] = static_cast<float>(linear_to_srgb(mean.z));
      }
      out[3] = static_cast<float>(hits * inv_samples);
      const Hit centre = scene.intersect(camera_ray(cam, i + 0.5, j + 0.5), 0.0);
      img.depth[px] = centre.hit() ? static_cast<float>(centre.t) : 0.0f;
      if (distractor) img.distractor[px] = seen_ball ? 1 : 0;
    }
  }
}

}  // namespace

double linear_to_srgb(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1.0 / 2.4) - 0.055;
}

ViewImage render_view(const Camera& cam, int threads, bool environment_background, const Vec3& gain,
                      const Distractor* distractor, const SceneTracer& scene) {
  ViewImage img;
  img.width = cam.width;
  img.height = cam.height;
  img.rgba.assign(static_cast<size_t>(img.width) * img.height * 4, 0.0f);
  img.depth.assign(static_cast<size_t>(img.width) * img.height, 0.0f);
  if (distractor) img.distractor.assign(static_cast<size_t>(img.width) * img.height, 0);
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  threads = std::min(threads, std::max(1, img.height));
  if (threads == 1) {
    render_rows(scene, cam, 0, 1, environment_background, gain, distractor, img);
    return img;
  }
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t)
    pool.emplace_back(render_rows, std::cref(scene), std::cref(cam), t, threads, environment_background,
                      std::cref(gain), distractor, std::ref(img));
  for (auto& th : pool) th.join();
  return img;
}

}  // namespace ablenerf::synth
