#include "samples/generator/render.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "core/error.h"

namespace dropfit::synth {
namespace {

std::uint64_t splitmix64(std::uint64_t& state) {
  std::uint64_t z = (state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// One octave of value noise: random values on a grid of spacing `scale`,
// smooth-step interpolated; about zero mean, unit variance at the nodes.
void add_value_noise(std::vector<float>& img, int w, int h, double scale, double amplitude, std::uint64_t seed) {
  const int gw = static_cast<int>(std::ceil(w / scale)) + 2, gh = static_cast<int>(std::ceil(h / scale)) + 2;
  std::vector<float> grid(static_cast<std::size_t>(gw) * gh);
  std::uint64_t state = seed;
  for (float& g : grid) {
    // Sum of four uniforms, scaled to unit variance.
    const std::uint64_t r = splitmix64(state);
    double s = 0;
    for (int k = 0; k < 4; ++k) s += static_cast<double>((r >> (16 * k)) & 0xFFFF) / 65535.0;
    g = static_cast<float>((s - 2.0) / std::sqrt(4.0 / 12.0));
  }
  auto smooth = [](double t) { return t * t * (3.0 - 2.0 * t); };
  for (int y = 0; y < h; ++y) {
    const double gy = (y + 0.5) / scale;
    const int iy = static_cast<int>(gy);
    const double ty = smooth(gy - iy);
    for (int x = 0; x < w; ++x) {
      const double gx = (x + 0.5) / scale;
      const int ix = static_cast<int>(gx);
      const double tx = smooth(gx - ix);
      const float* g0 = &grid[static_cast<std::size_t>(iy) * gw + ix];
      const float* g1 = g0 + gw;
      const double top = g0[0] + (g0[1] - g0[0]) * tx;
      const double bottom = g1[0] + (g1[1] - g1[0]) * tx;
      img[static_cast<std::size_t>(y) * w + x] += static_cast<float>(amplitude * (top + (bottom - top) * ty));
    }
  }
}

}  // namespace

FootageRenderer::FootageRenderer(FootageOptions options) : opt_(options) {
  if (opt_.width_px <= 0 || opt_.height_px <= 0) throw Error("footage size must be positive");
  if (opt_.supersample < 1) throw Error("supersample must be at least 1");
  const int w = opt_.width_px, h = opt_.height_px;
  background_.assign(static_cast<std::size_t>(w) * h, 0.0f);
  // Three octaves (amplitudes 1, 0.6, 0.35); smooth-step interpolation keeps
  // about 0.7 of the node variance, so rescale to the asked deviation.
  const double norm = opt_.texture_grey / std::sqrt(0.7 * (1.0 + 0.36 + 0.1225));
  std::uint64_t s = opt_.seed * 7919 + 17;
  add_value_noise(background_, w, h, opt_.texture_scale_px, norm, splitmix64(s));
  add_value_noise(background_, w, h, opt_.texture_scale_px / 3.0, 0.6 * norm, splitmix64(s));
  add_value_noise(background_, w, h, opt_.texture_scale_px / 9.0, 0.35 * norm, splitmix64(s));
  for (float& v : background_) v += static_cast<float>(opt_.background_grey);
}

capture::Image8 FootageRenderer::render(const MarkerFootage& footage, int frame) const {
  capture::Image8 out;
  render(footage, frame, out);
  return out;
}

void FootageRenderer::render(const MarkerFootage& footage, int frame, capture::Image8& out) const {
  const int w = opt_.width_px, h = opt_.height_px;
  if (frame < 0 || frame >= footage.n_frames()) throw Error(fmt::format("no frame {} in the footage", frame));
  if (static_cast<int>(footage.radius_px.size()) != footage.n_markers())
    throw Error("footage: one radius per marker expected");
  std::vector<float> img(background_);

  const int ss = opt_.supersample;
  // The edge profile 0.5 erfc(z / (sqrt(2) sigma)) tabulated over z = d - r
  // in [-kReach, kReach] sigma, linearly interpolated (error < 1e-5).
  constexpr double kReach = 5.0;
  constexpr int kSteps = 4096;
  std::vector<double> profile(kSteps + 2);
  for (int i = 0; i <= kSteps + 1; ++i)
    profile[i] = 0.5 * std::erfc((-kReach + 2.0 * kReach * i / kSteps) / std::sqrt(2.0));
  const double lut_scale = opt_.blur_px > 0 ? kSteps / (2.0 * kReach * opt_.blur_px) : 0.0;
  const auto edge = [&](double z) {  // z = d - r in pixels
    if (opt_.blur_px <= 0) return z < 0 ? 1.0 : 0.0;
    const double x = (z + kReach * opt_.blur_px) * lut_scale;
    if (x <= 0) return 1.0;
    if (x >= kSteps) return 0.0;
    const int i = static_cast<int>(x);
    return profile[i] + (profile[i + 1] - profile[i]) * (x - i);
  };
  for (int k = 0; k < footage.n_markers(); ++k) {
    const Eigen::Vector2d c = footage.centres_px.row(frame).segment<2>(2 * k).transpose();
    if (!c.allFinite()) continue;
    const double r = footage.radius_px[k];
    // Velocity in pixels per frame, from the neighbouring frames.
    Eigen::Vector2d v = Eigen::Vector2d::Zero();
    if (opt_.exposure_frames > 0) {
      const auto at = [&](int f) -> Eigen::Vector2d {
        if (f < 0 || f >= footage.n_frames()) return Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
        return footage.centres_px.row(f).segment<2>(2 * k).transpose();
      };
      const Eigen::Vector2d prev = at(frame - 1), next = at(frame + 1);
      if (prev.allFinite() && next.allFinite()) v = (next - prev) / 2.0;
      else if (next.allFinite()) v = next - c;
      else if (prev.allFinite()) v = c - prev;
    }
    const double smear = v.norm() * opt_.exposure_frames;  // pixels travelled while open
    const int n_t = std::max(1, static_cast<int>(std::ceil(3.0 * smear)) + 1);  // steps of 1/3 px or less
    std::vector<Eigen::Vector2d> positions;
    for (int t = 0; t < n_t; ++t) {
      const double tau = n_t == 1 ? 0.0 : opt_.exposure_frames * ((t + 0.5) / n_t - 0.5);
      positions.push_back(c + v * tau);
    }
    const double reach = r + 5.0 * opt_.blur_px + 0.5 * smear + 1.0;
    const int x0 = std::max(0, static_cast<int>(std::floor(c.x() - reach)));
    const int x1 = std::min(w, static_cast<int>(std::ceil(c.x() + reach)));
    const int y0 = std::max(0, static_cast<int>(std::floor(c.y() - reach)));
    const int y1 = std::min(h, static_cast<int>(std::ceil(c.y() + reach)));
    const Eigen::Vector2d seg_a = positions.front(), seg_ab = positions.back() - positions.front();
    const double seg_len2 = seg_ab.squaredNorm();
    const double reach_px = 5.0 * opt_.blur_px + 1.0;  // beyond r + reach_px a pixel is untouched
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        const Eigen::Vector2d centre(x + 0.5, y + 0.5);
        const double t = seg_len2 > 0 ? std::clamp((centre - seg_a).dot(seg_ab) / seg_len2, 0.0, 1.0) : 0.0;
        if ((centre - seg_a - t * seg_ab).norm() > r + reach_px) continue;
        double cover = 0.0;
        for (int sy = 0; sy < ss; ++sy)
          for (int sx = 0; sx < ss; ++sx) {
            const double px = x + (sx + 0.5) / ss, py = y + (sy + 0.5) / ss;
            for (const auto& p : positions) {
              const double dx = px - p.x(), dy = py - p.y();
              cover += edge(std::sqrt(dx * dx + dy * dy) - r);
            }
          }
        cover /= static_cast<double>(ss * ss * n_t);
        float& pix = img[static_cast<std::size_t>(y) * w + x];
        pix = static_cast<float>(pix * (1.0 - cover) + opt_.marker_grey * cover);
      }
  }

  for (const Occluder& o : footage.occluders) {
    const int x0 = std::max(0, static_cast<int>(std::floor(o.u0_px)));
    const int x1 = std::min(w, static_cast<int>(std::ceil(o.u1_px)));
    const int y0 = std::max(0, static_cast<int>(std::floor(o.v0_px)));
    const int y1 = std::min(h, static_cast<int>(std::ceil(o.v1_px)));
    for (int y = y0; y < y1; ++y) {
      const double ay = std::min<double>(y + 1, o.v1_px) - std::max<double>(y, o.v0_px);
      for (int x = x0; x < x1; ++x) {
        const double ax = std::min<double>(x + 1, o.u1_px) - std::max<double>(x, o.u0_px);
        const double a = std::clamp(ax, 0.0, 1.0) * std::clamp(ay, 0.0, 1.0);
        float& pix = img[static_cast<std::size_t>(y) * w + x];
        pix = static_cast<float>(pix * (1.0 - a) + o.grey * a);
      }
    }
  }

  out.width = w;
  out.height = h;
  out.pixels.resize(static_cast<std::size_t>(w) * h);
  std::uint64_t state = opt_.seed * 0x2545F4914F6CDD1Dull + static_cast<std::uint64_t>(frame) * 0x9E3779B97F4A7C15ull;
  // Sum of four bytes: mean 510, standard deviation sqrt(4 (256^2 - 1) / 12).
  const float noise_scale = static_cast<float>(opt_.noise_grey / std::sqrt(4.0 * (256.0 * 256.0 - 1.0) / 12.0));
  const std::size_t n = img.size();
  for (std::size_t i = 0; i < n; i += 2) {
    const std::uint64_t r = splitmix64(state);
    for (std::size_t j = 0; j < 2 && i + j < n; ++j) {
      const std::uint64_t bits = r >> (32 * j);
      const int s = static_cast<int>(bits & 0xFF) + static_cast<int>((bits >> 8) & 0xFF) +
                    static_cast<int>((bits >> 16) & 0xFF) + static_cast<int>((bits >> 24) & 0xFF);
      const float value = img[i + j] + noise_scale * static_cast<float>(s - 510);
      out.pixels[i + j] = static_cast<std::uint8_t>(std::clamp(value, 0.0f, 255.0f) + 0.5f);  // rounded
    }
  }
}

std::vector<std::string> write_footage_png(const std::string& folder, const MarkerFootage& footage,
                                           const FootageOptions& options, const std::string& prefix) {
  std::error_code ec;
  std::filesystem::create_directories(folder, ec);
  if (ec) throw InputError(folder, 0, 0, "", "cannot create the folder: " + ec.message());
  const FootageRenderer renderer(options);
  std::vector<std::string> files;
  capture::Image8 img;
  const std::vector<int> params{cv::IMWRITE_PNG_COMPRESSION, 1};
  for (int f = 0; f < footage.n_frames(); ++f) {
    renderer.render(footage, f, img);
    const std::string path = (std::filesystem::path(folder) / fmt::format("{}{:06d}.png", prefix, f)).string();
    const cv::Mat mat(img.height, img.width, CV_8UC1, img.pixels.data());
    if (!cv::imwrite(path, mat, params)) throw InputError(path, 0, 0, "", "cannot write the frame");
    files.push_back(path);
  }
  return files;
}

std::vector<std::string> write_footage_tiff12(const std::string& folder, const MarkerFootage& footage,
                                              const FootageOptions& options, const std::string& prefix) {
  std::error_code ec;
  std::filesystem::create_directories(folder, ec);
  if (ec) throw InputError(folder, 0, 0, "", "cannot create the folder: " + ec.message());
  const FootageRenderer renderer(options);
  std::vector<std::string> files;
  capture::Image8 img;
  cv::Mat wide;
  for (int f = 0; f < footage.n_frames(); ++f) {
    renderer.render(footage, f, img);
    const std::string path = (std::filesystem::path(folder) / fmt::format("{}{:06d}.tif", prefix, f)).string();
    const cv::Mat mat(img.height, img.width, CV_8UC1, img.pixels.data());
    mat.convertTo(wide, CV_16U, 4095.0 / 255.0);
    if (!cv::imwrite(path, wide)) throw InputError(path, 0, 0, "", "cannot write the frame");
    files.push_back(path);
  }
  return files;
}

void write_footage_video(const std::string& path, const MarkerFootage& footage, const FootageOptions& options,
                         const std::string& fourcc, double frame_rate_hz) {
  if (fourcc.size() != 4) throw Error(fmt::format("fourcc '{}' is not four characters", fourcc));
  cv::VideoWriter writer;
  bool opened = false;
  try {
    opened = writer.open(path, cv::CAP_FFMPEG, cv::VideoWriter::fourcc(fourcc[0], fourcc[1], fourcc[2], fourcc[3]),
                         frame_rate_hz, cv::Size(options.width_px, options.height_px), false);
  } catch (const cv::Exception&) {
    opened = false;
  }
  if (!opened) throw Error(fmt::format("{}: no video backend can write {} here", path, fourcc));
  const FootageRenderer renderer(options);
  capture::Image8 img;
  for (int f = 0; f < footage.n_frames(); ++f) {
    renderer.render(footage, f, img);
    writer.write(cv::Mat(img.height, img.width, CV_8UC1, img.pixels.data()));
  }
  writer.release();
}

}  // namespace dropfit::synth
