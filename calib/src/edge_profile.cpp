// The median profile across strong edges (edge_profile.hpp).
#include "crfcal/edge_profile.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"

namespace crfcal {

void EdgeProfileOptions::check() const {
  if (radius < 2 || radius > 50) throw InvalidInput("edge profile radius must be in [2, 50]", ErrorSubject::options);
  if (!(step > 0 && step <= 1)) throw InvalidInput("edge profile step must be in (0, 1]", ErrorSubject::options);
  if (!(edge_fraction > 0 && edge_fraction <= 0.5))
    throw InvalidInput("edge fraction must be in (0, 0.5]", ErrorSubject::options);
  if (!(min_contrast > 0 && min_contrast < 1)) throw InvalidInput("min contrast must be in (0, 1)", ErrorSubject::options);
  if (!(isolation > 0 && isolation <= 1)) throw InvalidInput("edge isolation must be in (0, 1]", ErrorSubject::options);
  if (max_edges < 1) throw InvalidInput("max edges must be positive", ErrorSubject::options);
  if (!(direction_sigma >= 0)) throw InvalidInput("direction sigma must be >= 0", ErrorSubject::options);
}

namespace {

cv::Mat unitImage(const cv::Mat& image) {
  if (image.channels() != 1 || image.empty())
    throw InvalidInput("edge profile needs a single-channel image", ErrorSubject::unspecified);
  cv::Mat out;
  const double scale = image.depth() == CV_8U ? 1.0 / 255 : image.depth() == CV_16U ? 1.0 / 65535 : 1.0;
  image.convertTo(out, CV_64F, scale);
  return out;
}

double bilinear(const cv::Mat& img, double x, double y) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  const double fx = x - x0, fy = y - y0;
  const double* r0 = img.ptr<double>(y0);
  const double* r1 = img.ptr<double>(y0 + 1);
  return (1 - fy) * ((1 - fx) * r0[x0] + fx * r0[x0 + 1]) + fy * ((1 - fx) * r1[x0] + fx * r1[x0 + 1]);
}

struct EdgePixel {
  double magnitude;
  double x, y;    // the edge's sub-pixel position
  double nx, ny;  // unit gradient (dark → bright)
};

// Strong edge pixels: gradient maxima along their own direction (non-maximum suppression), the strongest fraction.
std::vector<EdgePixel> strongEdges(const cv::Mat& img, const EdgeProfileOptions& o) {
  cv::Mat smooth;  // a new buffer: the profiles are sampled from `img` itself
  if (o.direction_sigma > 0) cv::GaussianBlur(img, smooth, cv::Size(), o.direction_sigma);
  else smooth = img;
  cv::Mat gx, gy;
  cv::Sobel(smooth, gx, CV_64F, 1, 0, 3);
  cv::Sobel(smooth, gy, CV_64F, 0, 1, 3);
  cv::Mat mag;
  cv::magnitude(gx, gy, mag);
  const int border = o.radius + 2;
  std::vector<EdgePixel> candidates;
  for (int y = border; y < img.rows - border; ++y)
    for (int x = border; x < img.cols - border; ++x) {
      const double m = mag.at<double>(y, x);
      if (!(m > 0)) continue;
      const double nx = gx.at<double>(y, x) / m, ny = gy.at<double>(y, x) / m;
      const double ahead = bilinear(mag, x + nx, y + ny), behind = bilinear(mag, x - nx, y - ny);
      if (m < ahead || m < behind) continue;
      // The vertex of the parabola through the three magnitudes: the edge's position along the normal to a
      // fraction of a pixel (without it the profiles of steps between two pixels are misaligned by ±0.5 px, which
      // widens their median and smears its lobes).
      const double curvature = ahead - 2 * m + behind;
      const double shift = curvature < 0 ? std::clamp(0.5 * (behind - ahead) / curvature, -0.5, 0.5) : 0.0;
      candidates.push_back({m, x + shift * nx, y + shift * ny, nx, ny});
    }
  const std::size_t interior =
      static_cast<std::size_t>(std::max(0, img.rows - 2 * border)) * static_cast<std::size_t>(std::max(0, img.cols - 2 * border));
  const std::size_t keep = std::min<std::size_t>(
      {candidates.size(), static_cast<std::size_t>(o.edge_fraction * double(interior)) + 1, std::size_t(o.max_edges)});
  std::partial_sort(candidates.begin(), candidates.begin() + static_cast<std::ptrdiff_t>(keep), candidates.end(),
                    [](const EdgePixel& a, const EdgePixel& b) { return a.magnitude > b.magnitude; });
  candidates.resize(keep);
  return candidates;
}

// Where `profile` crosses `level`, searching outward from the centre sample towards `direction` (±1); NaN if never.
double crossing(const std::vector<double>& offset, const std::vector<double>& profile, double level, int direction) {
  const int centre = static_cast<int>(profile.size() / 2);
  for (int i = centre; i + direction >= 0 && i + direction < static_cast<int>(profile.size()); i += direction) {
    const double a = profile[static_cast<std::size_t>(i)], b = profile[static_cast<std::size_t>(i + direction)];
    if ((a - level) * (b - level) <= 0 && a != b) {
      const double t = (level - a) / (b - a);
      return offset[static_cast<std::size_t>(i)] + t * (offset[static_cast<std::size_t>(i + direction)] - offset[static_cast<std::size_t>(i)]);
    }
  }
  return std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

EdgeProfile measureEdgeProfile(const cv::Mat& image, const EdgeProfileOptions& options) {
  options.check();
  const cv::Mat img = unitImage(image);
  if (img.rows < 2 * options.radius + 6 || img.cols < 2 * options.radius + 6)
    throw InvalidInput("image smaller than the edge profile", ErrorSubject::unspecified);
  const int half = static_cast<int>(std::lround(options.radius / options.step));
  const int n = 2 * half + 1;
  EdgeProfile result;
  for (int i = 0; i < n; ++i) result.offset.push_back((i - half) * options.step);
  result.profile.assign(static_cast<std::size_t>(n), 0.0);
  // The far ends: the outermost pixel on each side (samples with |d| ≥ radius − 1).
  const int far = static_cast<int>(std::lround(1.0 / options.step)) + 1;
  std::vector<double> sorted(img.begin<double>(), img.end<double>());
  std::sort(sorted.begin(), sorted.end());
  const double level_range = sorted[sorted.size() * 995 / 1000] - sorted[sorted.size() * 5 / 1000];
  const double min_step = std::max(options.min_contrast * level_range, 1e-9);
  std::vector<double> p(static_cast<std::size_t>(n));
  std::vector<std::vector<double>> profiles(static_cast<std::size_t>(n));
  for (const EdgePixel& e : strongEdges(img, options)) {
    for (int i = 0; i < n; ++i)
      p[static_cast<std::size_t>(i)] = bilinear(img, e.x + result.offset[static_cast<std::size_t>(i)] * e.nx,
                                                e.y + result.offset[static_cast<std::size_t>(i)] * e.ny);
    double low = 0, high = 0;
    for (int i = 0; i < far; ++i) {
      low += p[static_cast<std::size_t>(i)] / far;
      high += p[static_cast<std::size_t>(n - 1 - i)] / far;
    }
    const auto [pmin, pmax] = std::minmax_element(p.begin(), p.end());
    // An isolated step: the step between the far ends is most of the window's range (a thin line or a second edge
    // inside the window is not an edge profile).
    if (high - low < min_step || high - low < options.isolation * (*pmax - *pmin)) continue;
    for (int i = 0; i < n; ++i)
      profiles[static_cast<std::size_t>(i)].push_back((p[static_cast<std::size_t>(i)] - low) / (high - low));
    ++result.edges;
  }
  if (result.edges == 0) throw InvalidInput("no strong edge to profile", ErrorSubject::unspecified);
  for (int i = 0; i < n; ++i) {  // the median profile: robust to the texture next to some of the edges
    auto& v = profiles[static_cast<std::size_t>(i)];
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    result.profile[static_cast<std::size_t>(i)] = v[v.size() / 2];
  }
  result.width = crossing(result.offset, result.profile, 0.9, +1) - crossing(result.offset, result.profile, 0.1, -1);
  double top = -1e9, bottom = 1e9, far_high = 0, far_low = 0;
  for (int i = 0; i < far; ++i) {
    far_low += result.profile[static_cast<std::size_t>(i)] / far;
    far_high += result.profile[static_cast<std::size_t>(n - 1 - i)] / far;
  }
  for (int i = 0; i < n; ++i) {
    if (i > half) top = std::max(top, result.profile[static_cast<std::size_t>(i)]);
    if (i < half) bottom = std::min(bottom, result.profile[static_cast<std::size_t>(i)]);
  }
  result.overshoot = std::max(0.0, top - far_high);
  result.undershoot = std::max(0.0, far_low - bottom);
  return result;
}

}  // namespace crfcal
