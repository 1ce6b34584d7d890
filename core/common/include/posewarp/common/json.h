// The one strict JSON reader of posewarp's inputs (poses, animations, BVH maps, label maps, rig specs): nesting at
// most kMaxJsonDepth deep (checked before parsing, so a hostile file cannot exhaust the stack), no key twice in one
// object (nlohmann keeps the last of two; a label map or pose naming something twice is a mistake worth reporting),
// and numbers that fit a double (JSON has no NaN or Infinity).
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <string_view>

#include "posewarp/common/result.h"

namespace posewarp {

// Parses `text`; INVALID_ARGUMENT "<what> is not valid JSON: ...", "<what> nests deeper than ..." or
// "<what>: key "k" appears twice in one object ...". `Json` is nlohmann::json (keys sorted) or nlohmann::ordered_json
// (keys in the order written).
template <typename Json>
Result<Json> parse_json(std::string_view text, const std::string& what);

extern template Result<nlohmann::json> parse_json<nlohmann::json>(std::string_view, const std::string&);
extern template Result<nlohmann::ordered_json> parse_json<nlohmann::ordered_json>(std::string_view, const std::string&);

}  // namespace posewarp
