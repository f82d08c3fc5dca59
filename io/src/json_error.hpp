#pragma once
// One-line, printable descriptions of nlohmann::json errors. nlohmann's parse errors quote the last bytes read,
// raw: a binary file given as JSON would put bytes such as 0xFF on the terminal. Internal to crfcal_io.
#include <string>

#include <nlohmann/json.hpp>

namespace crfcal::io {

// "invalid JSON at byte N: <message with every byte outside printable ASCII shown as \xHH>".
inline std::string describeJsonError(const nlohmann::json::exception& error) {
  std::string text = error.what();
  // nlohmann prefixes "[json.exception.parse_error.101] parse error at line 1, column 2: "; the byte offset says it
  if (const auto colon = text.find(": "); colon != std::string::npos && text.rfind("[json.exception", 0) == 0)
    text.erase(0, colon + 2);
  std::string printable;
  for (const unsigned char c : text) {
    if (c >= 0x20 && c < 0x7F) {
      printable += static_cast<char>(c);
    } else {
      static const char* kHex = "0123456789ABCDEF";
      printable += "\\x";
      printable += kHex[c >> 4];
      printable += kHex[c & 15];
    }
  }
  if (const auto* parse = dynamic_cast<const nlohmann::json::parse_error*>(&error))
    return "invalid JSON at byte " + std::to_string(parse->byte) + ": " + printable;
  return "malformed JSON: " + printable;
}

}  // namespace crfcal::io
