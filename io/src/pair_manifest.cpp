#include "crfcal/io/pair_manifest.hpp"

#include <fstream>
#include <string>

#include "crfcal/error.hpp"

namespace crfcal::io {
namespace {

// The fields of one line: quoted strings or runs of characters other than white space and commas.
std::vector<std::string> fields(const std::string& line) {
  std::vector<std::string> out;
  std::size_t i = 0;
  while (i < line.size()) {
    const char c = line[i];
    if (c == ' ' || c == '\t' || c == ',' || c == '\r') {
      ++i;
    } else if (c == '"') {
      const std::size_t end = line.find('"', i + 1);
      if (end == std::string::npos) throw InvalidInput("unterminated quote");
      out.push_back(line.substr(i + 1, end - i - 1));
      i = end + 1;
    } else {
      std::size_t end = i;
      while (end < line.size() && line[end] != ' ' && line[end] != '\t' && line[end] != ',' && line[end] != '\r') ++end;
      out.push_back(line.substr(i, end - i));
      i = end;
    }
  }
  return out;
}

}  // namespace

std::vector<PairPaths> readPairManifest(const std::filesystem::path& manifest) {
  std::ifstream in(manifest);
  if (!in) throw Error(std::filesystem::exists(manifest) ? "cannot be read" : "no such file", manifest.string());
  const std::filesystem::path base = manifest.parent_path();
  std::vector<PairPaths> pairs;
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    const std::string where = manifest.string() + ":" + std::to_string(number);
    std::vector<std::string> f;
    try {
      f = fields(line);
    } catch (const InvalidInput& e) {
      throw Error(e.reason(), where);
    }
    if (f.empty() || f.front().rfind('#', 0) == 0) continue;
    if (pairs.empty() && f.size() == 2 && f[0] == "sharp" && f[1] == "blurred") continue;  // a CSV header
    if (f.size() != 2)
      throw Error("expected two paths (SHARP BLURRED), found " + std::to_string(f.size()), where);
    auto resolve = [&](const std::string& p) {
      const std::filesystem::path path(p);
      return path.is_absolute() ? path : base / path;
    };
    pairs.emplace_back(resolve(f[0]), resolve(f[1]));
  }
  if (pairs.empty()) throw Error("lists no pair (one \"SHARP BLURRED\" a line)", manifest.string());
  return pairs;
}

}  // namespace crfcal::io
