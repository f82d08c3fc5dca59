#pragma once
// The manifest of a joint calibration (`crfcal calibrate --pairs FILE`): one pair a line, "SHARP BLURRED" (separated
// by white space or one comma; .csv or .txt alike), paths relative to the manifest's directory unless absolute.
// Blank lines and lines starting with '#' are skipped; a first line "sharp,blurred" (a CSV header) too.
// Paths with spaces: quote them ("my sharp.jpg" "my blurred.jpg").
#include <filesystem>
#include <utility>
#include <vector>

namespace crfcal::io {

using PairPaths = std::pair<std::filesystem::path, std::filesystem::path>;  // sharp, blurred

// Throws crfcal::Error naming the manifest (and its line) when it cannot be read, a line does not hold exactly two
// paths, or it lists no pair.
std::vector<PairPaths> readPairManifest(const std::filesystem::path& manifest);

}  // namespace crfcal::io
