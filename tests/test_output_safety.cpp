// No command deletes or overwrites a file it did not write, nor an input, whatever the flags; a previous crfcal
// output (recognised by its manifest) is replaced as a whole; an unwritable location fails before the computation
// with the real reason; Ctrl-C leaves no partial output (issue 15, "Output").
#include <algorithm>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/output_guard.hpp"
#include "crfcal/io/output_manifest.hpp"
#include "test_support.hpp"

extern char** environ;

namespace crfcal {
namespace {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

using test::quote;
std::string bin() { return quote(test::crfcalBinary()); }

std::string contents(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeFile(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

// Every file below `dir` (relative path → bytes).
std::map<std::string, std::string> snapshot(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir))
    if (entry.is_regular_file()) files[entry.path().lexically_relative(dir).string()] = contents(entry.path());
  return files;
}

// Names in `dir` that look like crfcal's staging or temporary files.
std::vector<std::string> leftovers(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    if (name.find(".partial-") != std::string::npos || name.find(".old-") != std::string::npos ||
        name.find(".crfcal-probe-") != std::string::npos)
      names.push_back(entry.path().string());
  }
  return names;
}

// photos/ with the bundled pair and an unrelated file, as in the issue.
struct PhotosFolder {
  test::TempDir root;
  fs::path photos = root / "photos";
  std::map<std::string, std::string> before;
  PhotosFolder() {
    fs::create_directories(photos);
    fs::copy_file(test::samples() / "pairs" / "sharp.jpg", photos / "sharp.jpg");
    fs::copy_file(test::samples() / "pairs" / "blurred.jpg", photos / "blurred.jpg");
    writeFile(photos / "thesis.txt", "chapter 1\n");
    before = snapshot(photos);
  }
  std::string calibrate(const std::string& extra) const {
    return bin() + " calibrate -q " + quote(photos / "sharp.jpg") + " " + quote(photos / "blurred.jpg") + " -o " +
           quote(photos) + " --no-effects --rounds 0 " + extra;
  }
};

// A quick crfcal output directory (simulate: a few hundred milliseconds).
test::CommandResult simulate(const fs::path& out, const std::string& extra = "") {
  return test::run(bin() + " simulate -q --image " + quote(test::samples() / "levin09" / "im1.png") +
                   " --crf gamma:2.2 --kernel levin:2 -o " + quote(out) + " " + extra);
}

double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

TEST(OutputSafety, CalibrateIntoTheFolderOfItsPhotosIsRefusedAndKeepsEveryFile) {
  PhotosFolder folder;
  const auto t = Clock::now();
  const auto r = test::run(folder.calibrate(""));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_LT(secondsSince(t), 5.0) << "refused after the computation instead of before it";
  EXPECT_NE(r.output.find(folder.photos.string()), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("blurred.jpg"), std::string::npos) << "names the first foreign file: " << r.output;
  EXPECT_NE(r.output.find("--force"), std::string::npos) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << "one line: " << r.output;
  EXPECT_EQ(snapshot(folder.photos), folder.before);
  EXPECT_TRUE(leftovers(folder.root.path()).empty());
}

TEST(OutputSafety, CalibrateWithForceWritesBesidePhotosWithoutTouchingThem) {
  PhotosFolder folder;
  const auto r = test::run(folder.calibrate("--force"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const auto& [name, bytes] : folder.before) EXPECT_EQ(contents(folder.photos / name), bytes) << name;
  EXPECT_TRUE(fs::exists(folder.photos / "report.json"));
  const auto manifest = io::readManifest(folder.photos);
  ASSERT_TRUE(manifest);
  EXPECT_EQ(manifest->command, "calibrate");
  std::set<std::string> listed;
  for (const auto& f : manifest->files) listed.insert(f.path);
  EXPECT_TRUE(listed.count("report.json"));
  EXPECT_TRUE(listed.count("kernel.txt"));
  for (const auto& [name, bytes] : folder.before) EXPECT_FALSE(listed.count(name)) << name << " is not crfcal's";
  EXPECT_TRUE(leftovers(folder.root.path()).empty());

  // Still foreign content: without --force the next run is refused, and with it the photos survive again.
  EXPECT_EQ(test::run(folder.calibrate("")).exit_code, 1);
  ASSERT_EQ(test::run(folder.calibrate("--force")).exit_code, 0);
  for (const auto& [name, bytes] : folder.before) EXPECT_EQ(contents(folder.photos / name), bytes) << name;
}

TEST(OutputSafety, CompareIntoTheFolderOfTheReportItComparesKeepsTheReport) {
  test::TempDir root;
  const fs::path x = root / "x";
  ASSERT_EQ(simulate(x).exit_code, 0);
  const std::string truth = contents(x / "truth.json");
  const std::string compare = bin() + " compare -q " + quote(x / "truth.json") + " " +
                              quote(test::samples() / "pairs" / "truth.json") + " -o " + quote(x);
  // truth.json is listed in x's manifest, but it is an input of this command: x is not replaced as a whole.
  const auto refused = test::run(compare);
  EXPECT_EQ(refused.exit_code, 1) << refused.output;
  EXPECT_NE(refused.output.find("truth.json"), std::string::npos) << refused.output;
  EXPECT_EQ(contents(x / "truth.json"), truth);

  const auto forced = test::run(compare + " --force");
  ASSERT_EQ(forced.exit_code, 0) << forced.output;
  EXPECT_EQ(contents(x / "truth.json"), truth);
  EXPECT_TRUE(fs::exists(x / "compare.json"));
  EXPECT_TRUE(fs::exists(x / "sharp.png"));  // simulate's other files stay
  std::set<std::string> listed;
  const auto manifest = io::readManifest(x);
  ASSERT_TRUE(manifest);
  for (const auto& f : manifest->files) listed.insert(f.path);
  EXPECT_TRUE(listed.count("compare.json") && listed.count("truth.json") && listed.count("sharp.png"));
  EXPECT_TRUE(leftovers(root.path()).empty());
}

TEST(OutputSafety, PreviousCrfcalOutputIsReplacedAsAWhole) {
  test::TempDir root;
  const fs::path out = root / "out";
  ASSERT_EQ(test::run(bin() + " compare -q " + quote(test::samples() / "pairs" / "truth.json") + " " +
                      quote(test::samples() / "pairs" / "truth.json") + " -o " + quote(out))
                .exit_code,
            0);
  ASSERT_TRUE(fs::exists(out / "compare.json"));
  ASSERT_EQ(simulate(out).exit_code, 0);
  EXPECT_FALSE(fs::exists(out / "compare.json")) << "the previous output was not replaced as a whole";
  EXPECT_TRUE(fs::exists(out / "truth.json"));
  EXPECT_EQ(io::readManifest(out)->command, "simulate");
  EXPECT_TRUE(leftovers(root.path()).empty());
}

TEST(OutputSafety, EditedFileInAPreviousOutputIsNoLongerCrfcals) {
  test::TempDir root;
  const fs::path out = root / "out";
  ASSERT_EQ(simulate(out).exit_code, 0);
  writeFile(out / "truth.json", contents(out / "truth.json") + "my notes\n");
  const auto r = simulate(out);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("truth.json"), std::string::npos) << r.output;
  EXPECT_NE(contents(out / "truth.json").find("my notes"), std::string::npos);
}

TEST(OutputSafety, EmptyExistingDirectoryIsUsed) {
  test::TempDir root;
  fs::create_directories(root / "empty");
  const auto r = simulate(root / "empty");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(root / "empty" / io::kManifestName));
}

TEST(OutputSafety, OutputUnderAFileFailsBeforeTheComputationWithTheReason) {
  PhotosFolder folder;
  // A parent that is a file: "not a directory", whoever runs the test.
  const auto t = Clock::now();
  const auto r = test::run(bin() + " calibrate -q " + quote(folder.photos / "sharp.jpg") + " " +
                           quote(folder.photos / "blurred.jpg") + " -o " + quote(folder.photos / "thesis.txt" / "out"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_LT(secondsSince(t), 5.0) << "failed after the computation instead of before it";
  EXPECT_NE(r.output.find("not a directory"), std::string::npos) << r.output;
  EXPECT_EQ(snapshot(folder.photos), folder.before);
}

TEST(OutputSafety, ReadOnlyOutputLocationSaysPermissionDenied) {
  PhotosFolder folder;
  if (::geteuid() == 0) GTEST_SKIP() << "root writes into read-only directories";
  const fs::path locked = folder.root / "locked";
  fs::create_directories(locked);
  fs::permissions(locked, fs::perms::owner_read | fs::perms::owner_exec);
  const auto denied = test::run(bin() + " calibrate -q " + quote(folder.photos / "sharp.jpg") + " " +
                                quote(folder.photos / "blurred.jpg") + " -o " + quote(locked / "out"));
  fs::permissions(locked, fs::perms::owner_all);
  EXPECT_EQ(denied.exit_code, 1) << denied.output;
  EXPECT_NE(denied.output.find("permission denied"), std::string::npos) << denied.output;
}

TEST(OutputSafety, ExportOntoItsOwnInputIsRefusedAndTheInputUnchanged) {
  test::TempDir root;
  const fs::path report = root / "report.json";
  fs::copy_file(test::samples() / "pairs" / "truth.json", report);
  fs::create_hard_link(report, root / "linked.json");
  const std::string before = contents(report);
  for (const fs::path& target : {report, root / "." / "sub" / ".." / "report.json", root / "linked.json"}) {
    const auto r = test::run(bin() + " export " + quote(report) + " --format csv -o " + quote(target));
    EXPECT_EQ(r.exit_code, 1) << target << ": " << r.output;
    EXPECT_NE(r.output.find("input"), std::string::npos) << r.output;
    EXPECT_EQ(contents(report), before) << target;
  }
}

TEST(OutputSafety, ExportIntoAMissingDirectorySaysSo) {
  test::TempDir root;
  const auto r = test::run(bin() + " export " + quote(test::samples() / "pairs" / "truth.json") + " -o " +
                           quote(root / "missing" / "phi.csv"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("no such directory"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("Success"), std::string::npos) << r.output;
  const auto onto_directory = test::run(bin() + " export " + quote(test::samples() / "pairs" / "truth.json") +
                                        " --format csv -o " + quote(root.path()));
  EXPECT_EQ(onto_directory.exit_code, 1);
  EXPECT_NE(onto_directory.output.find("is a directory"), std::string::npos) << onto_directory.output;
}

TEST(OutputSafety, BenchJsonOverAFileCrfcalDidNotWriteIsRefusedBeforeTheComputation) {
  test::TempDir root;
  const fs::path json = root / "numbers.json";
  writeFile(json, "{\"mine\": 1}\n");
  const std::string bench = bin() + " bench chart -q --no-middlebury --seeds 1 --json " + quote(json);
  const auto t = Clock::now();
  const auto r = test::run(bench);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_LT(secondsSince(t), 5.0);
  EXPECT_NE(r.output.find("--force"), std::string::npos) << r.output;
  EXPECT_EQ(contents(json), "{\"mine\": 1}\n");
}

TEST(OutputSafety, JsonCrfcalWroteMayBeOverwritten) {
  test::TempDir root;
  const fs::path json = root / "numbers.json";
  io::writeJsonOutput(json, {{"value", 1}}, "bench test");
  EXPECT_NO_THROW(io::checkJsonOutputFile(json, {"bench test", {}}));
  writeFile(json, "[1, 2]");
  EXPECT_THROW(io::checkJsonOutputFile(json, {"bench test", {}}), Error);
  EXPECT_NO_THROW(io::checkJsonOutputFile(json, {"bench test", {}, /*force=*/true}));
  EXPECT_THROW(io::checkJsonOutputFile(json, {"bench test", {json}, /*force=*/true}), Error) << "an input, forced";
}

TEST(OutputSafety, ForcedOutputNeverReplacesAnInputOfTheSameName) {
  test::TempDir root;
  const fs::path dir = root / "dir";
  fs::create_directories(dir);
  writeFile(dir / "report.json", "the user's input");
  {
    io::OutputDirectory out(dir, {"test", {dir / "report.json"}, /*force=*/true});
    writeFile(out.file("report.json"), "crfcal's output");
    writeFile(out.file("other.txt"), "x");
    EXPECT_THROW(out.commit(), Error);
  }
  EXPECT_EQ(contents(dir / "report.json"), "the user's input");
  EXPECT_FALSE(fs::exists(dir / "other.txt")) << "checked before anything moves";
  EXPECT_TRUE(leftovers(root.path()).empty());
}

TEST(OutputSafety, OutputDirectoryWithoutCommitLeavesTheOldOutputIntact) {
  test::TempDir root;
  const fs::path dir = root / "dir";
  {
    io::OutputDirectory out(dir, {"test", {}});
    writeFile(out.file("a.txt"), "first");
    out.commit();
  }
  {
    io::OutputDirectory out(dir, {"test", {}});
    writeFile(out.file("a.txt"), "second");
  }  // unwound without commit
  EXPECT_EQ(contents(dir / "a.txt"), "first");
  EXPECT_FALSE(io::firstForeignEntry(dir, {}));
  EXPECT_TRUE(leftovers(root.path()).empty());
}

// Starts crfcal with `args` (stdout/stderr discarded); returns its process id.
pid_t spawnCrfcal(const std::vector<std::string>& args) {
  std::vector<std::string> all{test::crfcalBinary().string()};
  all.insert(all.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : all) argv.push_back(a.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 2, "/dev/null", O_WRONLY, 0);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  return rc == 0 ? pid : -1;
}

// Waits until `ready()` holds (or the process ended, or 60 s), then sends SIGINT; returns the wait status.
int interruptWhen(pid_t pid, const std::function<bool()>& ready) {
  const auto start = Clock::now();
  int status = 0;
  while (!ready() && secondsSince(start) < 60) {
    if (::waitpid(pid, &status, WNOHANG) == pid) return status;  // ended before it was interrupted
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // well inside the computation
  ::kill(pid, SIGINT);
  ::waitpid(pid, &status, 0);
  return status;
}

bool anyEntry(const fs::path& dir, const std::string& needle) {
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    if (it->path().string().find(needle) != std::string::npos) return true;
  return false;
}

TEST(OutputSafety, InterruptedCalibrateLeavesNoPartialOutputAndKeepsThePreviousOne) {
  test::TempDir root;
  const fs::path out = root / "out";
  ASSERT_EQ(simulate(out).exit_code, 0);
  const auto before = snapshot(out);
  const pid_t pid = spawnCrfcal({"calibrate", "-q", (test::samples() / "pairs" / "sharp.jpg").string(),
                                 (test::samples() / "pairs" / "blurred.jpg").string(), "-o", out.string()});
  ASSERT_GT(pid, 0);
  const int status = interruptWhen(pid, [&] { return anyEntry(root.path(), ".out.partial-"); });
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGINT) << "not ended by the interrupt: status " << status;
  EXPECT_EQ(snapshot(out), before);
  EXPECT_TRUE(leftovers(root.path()).empty());
}

TEST(OutputSafety, InterruptedForcedCalibrateLeavesOnlyTheFilesThatWereThere) {
  PhotosFolder folder;
  const pid_t pid = spawnCrfcal({"calibrate", "-q", (folder.photos / "sharp.jpg").string(),
                                 (folder.photos / "blurred.jpg").string(), "-o", folder.photos.string(), "--force"});
  ASSERT_GT(pid, 0);
  const int status = interruptWhen(pid, [&] { return anyEntry(folder.photos, ".crfcal.partial-"); });
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGINT) << "status " << status;
  EXPECT_EQ(snapshot(folder.photos), folder.before);
  EXPECT_TRUE(leftovers(folder.root.path()).empty());
}

TEST(OutputSafety, InterruptedBenchPairsRemovesItsHalfWrittenCases) {
  test::TempDir root;
  const fs::path out = root / "bench";
  ASSERT_EQ(simulate(out).exit_code, 0);  // a previous crfcal output in the way
  const auto before = snapshot(out);
  const pid_t pid = spawnCrfcal({"bench", "pairs", "--image", (test::samples() / "levin09" / "im1.png").string(),
                                 "--kernel", "levin:1", "-o", out.string()});
  ASSERT_GT(pid, 0);
  // Interrupted once the first case's files are in the staging directory.
  const int status = interruptWhen(pid, [&] { return anyEntry(root.path(), "case1/truth.json"); });
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGINT) << "status " << status;
  EXPECT_EQ(snapshot(out), before);
  EXPECT_TRUE(leftovers(root.path()).empty());
}

TEST(OutputSafety, EveryCommandThatWritesOutputDocumentsForce) {
  for (const char* command : {"calibrate", "chart", "compare", "simulate", "theory", "curves middlebury",
                              "study channels", "study noise", "study ratio", "bench pairs", "bench synthetic",
                              "bench chart", "bench effects", "bench raw-truth", "deblur", "bench deblur"}) {
    const auto help = test::run(bin() + " " + command + " --help");
    EXPECT_EQ(help.exit_code, 0) << command;
    EXPECT_NE(help.output.find("--force"), std::string::npos) << command;
  }
}

}  // namespace
}  // namespace crfcal
