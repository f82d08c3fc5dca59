// crfcal theory: reproduces the seed's Fig. 1 and checks Theorem 1 (0 ≤ Γ ≤ Imax − Imin, Sec. 3) on real images.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <map>

#include <opencv2/imgproc.hpp>

#include "command.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/plot.hpp"
#include "crfcal/theory.hpp"
#include "crfcal/theory_deblur.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {

namespace fs = std::filesystem;

struct TheoryArgs {
  std::string output;
  std::string images_dir;  // default: <samples>/levin09
  bool quiet = false;
  bool force = false;  // write into an output directory holding other files (never deletes them)
};

std::string format(const char* fmt, auto... args) {
  char buffer[1024];
  std::snprintf(buffer, sizeof buffer, fmt, args...);
  return buffer;
}

const std::vector<int> kKernelLengths{10, 20, 30, 80};  // Fig. 1(a)/(b)

bool isImageFile(const fs::path& path) {
  std::string ext = path.extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".tif" || ext == ".tiff" || ext == ".bmp" ||
         ext == ".pgm";
}

// Sharp images of DIR (every image file whose name does not start with "kernel") and its kernel*.txt files.
void listInputs(const fs::path& dir, std::vector<fs::path>& images, std::vector<fs::path>& kernels) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw Error("not a directory", dir.string());
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (!entry.is_regular_file()) continue;
    const std::string name = entry.path().filename().string();
    if (name.rfind("kernel", 0) == 0) {
      if (entry.path().extension() == ".txt") kernels.push_back(entry.path());
    } else if (isImageFile(entry.path())) {
      images.push_back(entry.path());
    }
  }
  std::sort(images.begin(), images.end());
  std::sort(kernels.begin(), kernels.end());
  if (images.empty()) throw Error("no sharp images (png/jpg/tif/bmp/pgm) found", dir.string());
}

// ---- Fig. 1(a) -------------------------------------------------------------------------------------------

std::string writeFig1a(const io::OutputDirectory& out) {
  theory::ProfileOptions options;
  options.kernel_lengths = kKernelLengths;
  const auto result = theory::blurProfiles(theory::fig1Signal(), options);
  const size_t n = result.sharp.size();
  std::vector<double> x(n);
  for (size_t i = 0; i < n; ++i) x[i] = double(i);

  std::string csv = "x,I";
  for (const auto& p : result.profiles)
    csv += format(",B_%d,Bhat_%d,Gamma_%d,near_edge_%d", p.kernel_length, p.kernel_length, p.kernel_length, p.kernel_length);
  csv += "\n";
  for (size_t i = 0; i < n; ++i) {
    csv += format("%zu,%.10g", i, result.sharp[i]);
    for (const auto& p : result.profiles)
      csv += format(",%.10g,%.10g,%.10g,%d", p.blurred[i], p.intensity_blurred[i], p.gamma[i], int(p.near_edge[i]));
    csv += "\n";
  }
  io::writeTextFile(out.file("fig1a.csv"), csv);

  std::vector<io::PlotSeries> series;
  for (size_t k = 0; k < result.profiles.size(); ++k) {
    const auto& p = result.profiles[k];
    io::PlotSeries s;
    s.x = x;
    s.y = p.gamma;
    s.color = io::seriesColor(static_cast<int>(k));
    s.label = format("box %d px (max on smooth parts %.4f)", p.kernel_length, p.max_abs_gamma_smooth);
    series.push_back(std::move(s));
  }
  io::PlotOptions plot;
  plot.title = "Fig. 1(a): Gamma = B - B^ on a 1-D signal, phi = gamma 2.2";
  plot.x_label = "x (px)";
  plot.y_label = "Gamma";
  plot.size = {960, 540};
  plot.y_min = -0.02;
  plot.y_max = 0.26;
  io::writePlot(out.file("fig1a_gamma_profiles.png"), series, plot);

  // The signal itself with B and B^ for the 30 px kernel.
  const auto& p30 = result.profiles[2];
  std::vector<io::PlotSeries> signal(3);
  signal[0] = {x, result.sharp, cv::Scalar(0, 0, 0), "sharp I", 2, false, false};
  signal[1] = {x, p30.intensity_blurred, io::seriesColor(1), "B^ = I (x) K, box 30 px", 2, false, true};
  signal[2] = {x, p30.blurred, io::seriesColor(0), "B = psi(phi(I) (x) K), box 30 px", 2, false, false};
  io::PlotOptions signal_plot = plot;
  signal_plot.title = "Fig. 1(a) signal: I, intensity blur B^ and irradiance blur B (30 px)";
  signal_plot.y_label = "intensity";
  signal_plot.y_min = 0;
  signal_plot.y_max = 1.05;
  io::writePlot(out.file("fig1a_signal.png"), signal, signal_plot);
  return "Fig. 1(a) (1-D signal, gamma 2.2):\n" + result.summary();
}

// ---- Fig. 1(b)/(c) ---------------------------------------------------------------------------------------

cv::Mat toBgr8(const cv::Mat& unit) {
  cv::Mat grey, bgr;
  cv::Mat clamped;
  cv::max(cv::min(unit, 1.0), 0.0, clamped);
  clamped.convertTo(grey, CV_8U, 255.0);
  cv::cvtColor(grey, bgr, cv::COLOR_GRAY2BGR);
  return bgr;
}

std::string writeFig1bc(const io::OutputDirectory& out) {
  std::map<int, theory::PatternResult> results;
  for (int length : kKernelLengths) {
    theory::PatternOptions options;
    options.motion_length = length;
    results.emplace(length, theory::analyzePattern(options));
  }
  const theory::PatternResult& main = results.at(20);  // Fig. 1(c): 20 px motion
  const int row = main.sharp.rows / 2;

  // Fig. 1(b): Γ along the middle row for the four kernel sizes.
  std::string csv = "x,I";
  for (int length : kKernelLengths) csv += format(",Gamma_%d", length);
  csv += "\n";
  std::vector<double> x(static_cast<size_t>(main.sharp.cols));
  for (int c = 0; c < main.sharp.cols; ++c) {
    x[static_cast<size_t>(c)] = c;
    csv += format("%d,%.10g", c, main.sharp.at<double>(row, c));
    for (int length : kKernelLengths) csv += format(",%.10g", results.at(length).gamma.at<double>(row, c));
    csv += "\n";
  }
  io::writeTextFile(out.file("fig1b_kernel_size.csv"), csv);
  std::vector<io::PlotSeries> series;
  for (size_t k = 0; k < kKernelLengths.size(); ++k) {
    const auto& r = results.at(kKernelLengths[k]);
    io::PlotSeries s;
    s.x = x;
    s.y.assign(r.gamma.ptr<double>(row), r.gamma.ptr<double>(row) + r.gamma.cols);
    s.color = io::seriesColor(static_cast<int>(k));
    s.label = format("%d px motion", kKernelLengths[k]);
    series.push_back(std::move(s));
  }
  io::PlotSeries pattern_row;
  pattern_row.x = x;
  pattern_row.y.assign(main.sharp.ptr<double>(row), main.sharp.ptr<double>(row) + main.sharp.cols);
  for (double& v : pattern_row.y) v *= 0.3;
  pattern_row.color = cv::Scalar(150, 150, 150);
  pattern_row.label = "pattern I (scaled x0.3)";
  pattern_row.thickness = 1;
  series.push_back(pattern_row);
  io::PlotOptions plot;
  plot.title = "Fig. 1(b): Gamma along the block pattern vs kernel size (gamma 2.2)";
  plot.x_label = "x (px)";
  plot.y_label = "Gamma";
  plot.size = {1100, 500};
  plot.y_min = -0.02;
  plot.y_max = 0.32;
  io::writePlot(out.file("fig1b_kernel_size.png"), series, plot);

  // Fig. 1(c): I, B, Γ stacked (Γ as grey scaled to its maximum, and as a signed colour map).
  double gmax = std::max(main.max_gamma, 1e-12);
  const cv::Mat separator(4, main.sharp.cols, CV_8UC3, cv::Scalar(0, 0, 255));
  cv::Mat stacked;
  cv::vconcat(std::vector<cv::Mat>{toBgr8(main.sharp), separator, toBgr8(main.blurred), separator,
                                   toBgr8(main.gamma / gmax)},
              stacked);
  io::writeImage(out.file("fig1c_pattern.png"), stacked);
  io::writeSignedMap(out.file("fig1c_gamma_signed.png"), main.gamma);

  std::string edges = "motion_px,block,edge,x,contrast,max_gamma,predicted_max_gamma\n";
  std::vector<io::PlotSeries> edge_series;
  for (size_t k = 0; k < kKernelLengths.size(); ++k) {
    const int length = kKernelLengths[k];
    io::PlotSeries s;
    s.color = io::seriesColor(static_cast<int>(k));
    s.label = format("%d px motion", length);
    s.markers = true;
    for (const auto& e : results.at(length).edges) {
      edges += format("%d,%d,%s,%d,%.6g,%.10g,%.10g\n", length, e.block, e.rising ? "rising" : "falling", e.x,
                      e.contrast, e.max_gamma, e.predicted_max_gamma);
      s.x.push_back(e.contrast);
      s.y.push_back(e.max_gamma);
    }
    edge_series.push_back(std::move(s));
  }
  io::writeTextFile(out.file("fig1c_edges.csv"), edges);
  io::PlotSeries bound;
  bound.x = {0.0, 0.4};  // Γ = contrast, clipped to the plotted range
  bound.y = {0.0, 0.4};
  bound.color = cv::Scalar(120, 120, 120);
  bound.label = "Theorem 1 bound Imax - Imin";
  bound.dashed = true;
  bound.thickness = 1;
  edge_series.push_back(bound);
  io::PlotOptions edge_plot;
  edge_plot.title = "Fig. 1(c): max Gamma per edge (4 kernels coincide)";
  edge_plot.x_label = "edge contrast Imax - Imin";
  edge_plot.y_label = "max Gamma";
  edge_plot.x_min = 0;
  edge_plot.x_max = 1.05;
  edge_plot.y_min = 0;
  edge_plot.y_max = 0.4;
  io::writePlot(out.file("fig1c_edges.png"), edge_series, edge_plot);
  return "Fig. 1(c) (blocks on black, 20 px motion, gamma 2.2):\n" + main.summary();
}

// ---- Theorem 1 -------------------------------------------------------------------------------------------

struct CurveTotals {
  bool convex = false;
  double min_gamma = 1e300, max_excess = -1e300, max_gamma = -1e300, min_corr = 1, max_smooth = 0;
  long long lower = 0, upper = 0, pixels = 0;
  int runs = 0;
};

std::string checkTheorem(const io::OutputDirectory& out, const fs::path& images_dir, Progress& progress) {
  std::vector<fs::path> image_paths, kernel_paths;
  listInputs(images_dir, image_paths, kernel_paths);
  std::vector<std::pair<std::string, cv::Mat>> kernels;
  if (kernel_paths.empty()) {
    for (int k = 1; k <= 8; ++k) kernels.emplace_back(format("levin%d", k), io::kernelFromSpec(format("levin:%d", k)));
  } else {
    for (const auto& path : kernel_paths) kernels.emplace_back(path.stem().string(), io::readKernel(path));
  }
  const auto curves = theory::referenceCurves();
  std::vector<ResponseCurve> tables;
  for (const auto& c : curves) tables.emplace_back(c.model);

  std::string csv =
      "image,kernel,curve,convex,min_gamma,max_gamma,max_upper_excess,lower_violations,upper_violations,pixels,"
      "uniform_pixels,max_abs_gamma_uniform,max_abs_gamma_smooth,mean_gamma_edge,max_tightness,correlation\n";
  std::vector<CurveTotals> totals(curves.size());
  const size_t jobs = image_paths.size() * kernels.size();
  size_t done = 0;
  for (const auto& image_path : image_paths) {
    const cv::Mat image = io::readGrayUnit(image_path);
    for (const auto& [kernel_name, kernel] : kernels) {
      const auto context = theory::makeBlurContext(image, kernel);
      for (size_t c = 0; c < curves.size(); ++c) {
        const auto check = theory::checkTheorem1(context, tables[c]);
        csv += format("%s,%s,%s,%d,%.6e,%.6e,%.6e,%lld,%lld,%lld,%lld,%.3e,%.6e,%.6e,%.6f,%.4f\n",
                      image_path.filename().string().c_str(), kernel_name.c_str(), curves[c].name.c_str(),
                      int(check.curve_convex), check.min_gamma, check.max_gamma, check.max_upper_excess,
                      check.lower_violations, check.upper_violations, check.pixels, check.uniform_pixels,
                      check.max_abs_gamma_uniform, check.max_abs_gamma_smooth, check.mean_gamma_edge,
                      check.max_tightness, check.correlation);
        auto& t = totals[c];
        t.convex = check.curve_convex;
        t.min_gamma = std::min(t.min_gamma, check.min_gamma);
        t.max_excess = std::max(t.max_excess, check.max_upper_excess);
        t.max_gamma = std::max(t.max_gamma, check.max_gamma);
        t.min_corr = std::min(t.min_corr, check.correlation);
        t.max_smooth = std::max(t.max_smooth, check.max_abs_gamma_smooth);
        t.lower += check.lower_violations;
        t.upper += check.upper_violations;
        t.pixels += check.pixels;
        ++t.runs;
      }
      ++done;
      progress.update(double(done) / double(jobs), format("%zu/%zu", done, jobs));
    }
  }
  io::writeTextFile(out.file("theorem1.csv"), csv);

  const double tolerance = theory::Theorem1Options{}.tolerance;
  std::string text = format(
      "Theorem 1 (0 <= Gamma <= Imax - Imin for convex phi), %zu images x %zu kernels from %s, before quantisation, "
      "tolerance %.0e:\n",
      image_paths.size(), kernels.size(), images_dir.string().c_str(), tolerance);
  text += format("%-20s %-6s %12s %16s %9s %9s %8s %16s %9s  %s\n", "curve", "convex", "worst_min_G",
                 "worst_G-(Imax-Imin)", "lower_viol", "upper_viol", "max_G", "max|G|_smooth", "min_corr", "verdict");
  for (size_t c = 0; c < curves.size(); ++c) {
    const auto& t = totals[c];
    std::string verdict;
    if (t.convex) verdict = t.lower + t.upper == 0 ? "holds" : "VIOLATED";
    else verdict = t.lower > 0 ? "lower bound fails (phi not convex)" : "holds although phi is not convex";
    if (t.upper > 0) verdict += "; UPPER BOUND VIOLATED";
    text += format("%-20s %-6s %+12.3e %+16.3e %9lld %9lld %8.4f %16.2e %9.3f  %s\n", curves[c].name.c_str(),
                   t.convex ? "yes" : "no", t.min_gamma, t.max_excess, t.lower, t.upper, t.max_gamma, t.max_smooth,
                   t.min_corr, verdict.c_str());
  }
  return text;
}

// ---- Fig. 3 / Fig. 4 (Sec. 3.2) -----------------------------------------------------------------------------

std::string writeFig3(const io::OutputDirectory& out) {
  const theory::StepEdgeResult step = theory::stepEdgeDeconvolution();
  std::string csv = "x,I,B,Bhat,P,B_deconvolved,P_deconvolved,irradiance_deconvolved\n";
  std::vector<double> x(step.sharp.size());
  for (size_t i = 0; i < x.size(); ++i) {
    x[i] = double(i);
    csv += format("%zu,%.10g,%.10g,%.10g,%.10g,%.10g,%.10g,%.10g\n", i, step.sharp[i], step.blurred[i],
                  step.intensity_blurred[i], step.artefact[i], step.deconvolved[i], step.artefact_deconvolved[i],
                  step.irradiance_deconvolved[i]);
  }
  io::writeTextFile(out.file("fig3_step_edge.csv"), csv);
  std::vector<io::PlotSeries> series(6);
  series[0] = {x, step.sharp, cv::Scalar(0, 0, 0), "sharp I", 2, false, false};
  series[1] = {x, step.blurred, io::seriesColor(0), "B = psi(phi(I) (x) K)", 1, false, false};
  series[2] = {x, step.artefact, io::seriesColor(1), "P = B - I (x) K", 2, false, false};
  series[3] = {x, step.deconvolved, io::seriesColor(2), "B (x) K^-1 = I + P (x) K^-1", 2, false, false};
  series[4] = {x, step.artefact_deconvolved, io::seriesColor(3), "P (x) K^-1", 2, false, true};
  series[5] = {x, step.irradiance_deconvolved, io::seriesColor(4), "psi(phi(B) (x) K^-1)", 1, false, true};
  io::PlotOptions plot;
  plot.title = "Fig. 3: step edge, box 21 px, gamma 2.2, K^-1 as Wiener (nsr 1e-2)";
  plot.x_label = "x (px)";
  plot.y_label = "intensity";
  plot.size = {960, 540};
  plot.y_min = -0.3;
  plot.y_max = 1.2;
  io::writePlot(out.file("fig3_step_edge.png"), series, plot);
  return "Fig. 3 (Eq. 18):\n" + step.summary();
}

std::string writeFig4(const io::OutputDirectory& out, const fs::path& images_dir) {
  std::vector<fs::path> images, kernel_files;
  listInputs(images_dir, images, kernel_files);
  const cv::Mat kernel = kernel_files.empty() ? io::kernelFromSpec("levin:2") : io::readKernel(kernel_files.front());
  const cv::Mat sharp = io::readGrayUnit(images.front());
  const theory::TvComparison tv = theory::tvComparison(sharp, kernel);
  const cv::Mat separator(sharp.rows, 4, CV_8UC3, cv::Scalar(0, 0, 255));
  cv::Mat results, errors;
  cv::hconcat(std::vector<cv::Mat>{toBgr8(tv.blurred), separator, toBgr8(tv.tv_blurred), separator,
                                   toBgr8(tv.tv_intensity_blurred), separator, toBgr8(tv.tv_irradiance)},
              results);
  io::writeImage(out.file("fig4_tv_results.png"), results);
  cv::hconcat(std::vector<cv::Mat>{tv.tv_blurred - tv.sharp, tv.tv_intensity_blurred - tv.sharp,
                                   tv.tv_irradiance - tv.sharp},
              errors);
  io::writeSignedMap(out.file("fig4_tv_errors_signed.png"), errors, 0.2);
  std::string csv = "input,domain,psnr_db,ssim\n";
  csv += format("B,intensity,%.4f,%.5f\n", tv.psnr_tv_blurred, tv.ssim_tv_blurred);
  csv += format("Bhat,intensity,%.4f,%.5f\n", tv.psnr_tv_intensity_blurred, tv.ssim_tv_intensity_blurred);
  csv += format("B,irradiance,%.4f,%.5f\n", tv.psnr_tv_irradiance, tv.ssim_tv_irradiance);
  io::writeTextFile(out.file("fig4_tv.csv"), csv);
  return "Fig. 4 (" + images.front().filename().string() + ", " +
         (kernel_files.empty() ? std::string("levin:2") : kernel_files.front().filename().string()) +
         ", gamma 2.2; results: B | TV(B) | TV(B^) | psi(TV(phi(B))); errors: the last three - I, +-0.2):\n" +
         tv.summary();
}

int runTheory(const TheoryArgs& args) {
  Progress progress(args.quiet);
  const fs::path images_dir = args.images_dir.empty() ? io::samplesDirectory() / "levin09" : fs::path(args.images_dir);
  io::OutputDirectory out(args.output, {"theory", {images_dir}, args.force});
  progress.stage("fig. 1(a) profiles");
  const std::string fig1a = writeFig1a(out);
  progress.done();
  progress.stage("fig. 1(b)/(c) block pattern");
  const std::string fig1c = writeFig1bc(out);
  progress.done();
  progress.stage("fig. 3 step edge, fig. 4 TV");
  const std::string fig34 = writeFig3(out) + "\n" + writeFig4(out, images_dir);
  progress.done();
  progress.stage("theorem 1 check");
  const std::string theorem = checkTheorem(out, images_dir, progress);
  progress.done();
  const std::string summary = theorem + "\n" + fig1a + "\n" + fig1c + "\n" + fig34;
  io::writeTextFile(out.file("summary.txt"), summary);
  out.commit();
  std::printf("%s\nwrote %s/{fig1a_gamma_profiles.png, fig1a_signal.png, fig1a.csv, fig1b_kernel_size.png, "
              "fig1b_kernel_size.csv, fig1c_pattern.png, fig1c_gamma_signed.png, fig1c_edges.png, fig1c_edges.csv, "
              "fig3_step_edge.png, fig3_step_edge.csv, fig4_tv_results.png, fig4_tv_errors_signed.png, fig4_tv.csv, "
              "theorem1.csv, summary.txt}\n",
              summary.c_str(), args.output.c_str());
  return kExitOk;
}

const CommandRegistration registration(
    20, "theory", "Reproduce Fig. 1, 3, 4 and check Theorem 1 (0 <= Gamma <= Imax - Imin) on sharp images (seed Sec. 3)",
    [](CLI::App& command) {
      auto args = std::make_shared<TheoryArgs>();
      command.add_option("-o,--output", args->output, "Output directory (created or replaced atomically)")->required();
      command.add_flag("--force", args->force, kForceHelp);
      command.add_option("--images-dir", args->images_dir,
                         "Directory of sharp images (kernel*.txt there are used as kernels, else the 8 Levin "
                         "kernels); default: the bundled samples/levin09");
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runTheory(*args); };
    });

}  // namespace
}  // namespace crfcal::app
