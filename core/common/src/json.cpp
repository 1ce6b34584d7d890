// The strict JSON reader (see json.h).
#include "posewarp/common/json.h"

#include <algorithm>
#include <cctype>
#include <set>
#include <vector>

#include "posewarp/common/input_file.h"

namespace posewarp {
namespace {

bool mentions_non_finite(std::string_view text) {
  std::string lower(text.size(), ' ');
  std::transform(text.begin(), text.end(), lower.begin(), [](unsigned char c) { return std::tolower(c); });
  return lower.find("nan") != std::string::npos || lower.find("inf") != std::string::npos;
}

}  // namespace

template <typename Json>
Result<Json> parse_json(std::string_view text, const std::string& what) {
  POSEWARP_RETURN_IF_ERROR(check_json_depth(text, what));
  std::vector<std::set<std::string>> open_objects;
  std::string duplicate;
  const typename Json::parser_callback_t callback = [&](int /*depth*/, typename Json::parse_event_t event,
                                                        Json& parsed) {
    switch (event) {
      case Json::parse_event_t::object_start: open_objects.emplace_back(); break;
      case Json::parse_event_t::object_end:
        if (!open_objects.empty()) open_objects.pop_back();
        break;
      case Json::parse_event_t::key:
        if (!open_objects.empty() && parsed.is_string() &&
            !open_objects.back().insert(parsed.template get<std::string>()).second && duplicate.empty()) {
          duplicate = parsed.template get<std::string>();
        }
        break;
      default: break;
    }
    return true;
  };
  Json doc;
  try {
    doc = Json::parse(text, callback);
  } catch (const typename Json::exception& error) {
    // parse_error for bad syntax, out_of_range for a number too large for a double (1e999).
    std::string message = what + " is not valid JSON: " + error.what();
    if (error.id == 406 || mentions_non_finite(text)) {
      message += " (JSON has no NaN or Infinity: write every number as a finite value)";
    }
    return invalid_argument_error(message);
  }
  if (!duplicate.empty()) {
    return invalid_argument_error(what + ": key \"" + duplicate +
                                  "\" appears twice in one object; give each name or field only once");
  }
  return doc;
}

template Result<nlohmann::json> parse_json<nlohmann::json>(std::string_view, const std::string&);
template Result<nlohmann::ordered_json> parse_json<nlohmann::ordered_json>(std::string_view, const std::string&);

}  // namespace posewarp
