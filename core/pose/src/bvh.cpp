// BVH import: parse HIERARCHY and MOTION, check the map against both trees, convert each frame to a pose.
#include "posewarp/pose/bvh.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <string_view>

#include "json_util.h"

namespace posewarp::pose {
namespace {

using detail::join;

// Largest magnitude of a frame value (degrees, or the clip's length unit).
constexpr double kMaxChannelValue = 1e4;

enum class Channel { kXposition, kYposition, kZposition, kXrotation, kYrotation, kZrotation };

struct BvhJoint {
  std::string name;
  int parent = -1;  // index into BvhClip::joints; -1 for the root
  int line = 0;
  std::vector<Channel> channels;
  int first_channel = 0;  // index of its first value on a frame line
  bool has_channels = false;
};

struct BvhClip {
  std::vector<BvhJoint> joints;  // file order: parents before children
  int channel_count = 0;
  int frame_count = 0;
  double frame_time_s = 0.0;
  std::vector<double> values;  // frame_count x channel_count, frame-major
};

struct Token {
  std::string_view text;
  int line = 0;
};

std::string quoted(std::string_view text) {
  std::string q(1, '"');
  q += text;
  q += '"';
  return q;
}

std::string line_prefix(int line) {
  return "BVH line " + std::to_string(line) + ": ";
}

std::vector<std::string_view> split_lines(const std::string& text) {
  std::vector<std::string_view> lines;
  std::string_view rest(text);
  if (rest.substr(0, 3) == "\xEF\xBB\xBF") rest.remove_prefix(3);  // a UTF-8 byte order mark
  while (!rest.empty()) {
    const size_t end = rest.find('\n');
    std::string_view line = rest.substr(0, end);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    lines.push_back(line);
    if (end == std::string_view::npos) break;
    rest.remove_prefix(end + 1);
  }
  return lines;
}

bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

// Whitespace-separated words; braces are words of their own even when written against a name.
void tokenize(std::string_view line, int line_number, std::vector<Token>& tokens) {
  size_t i = 0;
  while (i < line.size()) {
    if (is_space(line[i])) {
      ++i;
    } else if (line[i] == '{' || line[i] == '}') {
      tokens.push_back({line.substr(i, 1), line_number});
      ++i;
    } else {
      const size_t start = i;
      while (i < line.size() && !is_space(line[i]) && line[i] != '{' && line[i] != '}') ++i;
      tokens.push_back({line.substr(start, i - start), line_number});
    }
  }
}

bool equals_ignoring_case(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::tolower(static_cast<unsigned char>(x)) == std::tolower(static_cast<unsigned char>(y));
         });
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space(s.back())) s.remove_suffix(1);
  return s;
}

Result<double> parse_number(std::string_view word, int line) {
  std::string_view digits = word;
  if (!digits.empty() && digits.front() == '+') digits.remove_prefix(1);
  double value = 0.0;
  const auto [end, error] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
  if (digits.empty() || error != std::errc() || end != digits.data() + digits.size()) {
    return invalid_argument_error(line_prefix(line) + "\"" + std::string(word) + "\" is not a number");
  }
  if (!std::isfinite(value)) {
    return invalid_argument_error(line_prefix(line) + "\"" + std::string(word) + "\" is not a finite number");
  }
  return value;
}

Result<int64_t> parse_count(std::string_view word, int line, std::string_view what) {
  int64_t value = 0;
  const auto [end, error] = std::from_chars(word.data(), word.data() + word.size(), value);
  if (word.empty() || error != std::errc() || end != word.data() + word.size() || value < 0) {
    return invalid_argument_error(line_prefix(line) + std::string(what) + " must be a whole number (got \"" +
                                  std::string(word) + "\")");
  }
  return value;
}

Result<Channel> parse_channel(std::string_view word, int line) {
  static constexpr std::pair<std::string_view, Channel> kNames[] = {
      {"Xposition", Channel::kXposition}, {"Yposition", Channel::kYposition}, {"Zposition", Channel::kZposition},
      {"Xrotation", Channel::kXrotation}, {"Yrotation", Channel::kYrotation}, {"Zrotation", Channel::kZrotation}};
  for (const auto& [name, channel] : kNames) {
    if (equals_ignoring_case(word, name)) return channel;
  }
  return invalid_argument_error(line_prefix(line) + "unknown channel \"" + std::string(word) +
                                "\"; use Xposition, Yposition, Zposition, Xrotation, Yrotation or Zrotation");
}

// HIERARCHY: one ROOT with nested JOINT and End Site blocks. Iterative, so a deeply nested file cannot exhaust
// the stack.
Status parse_hierarchy(const std::vector<Token>& tokens, int motion_line, BvhClip& clip) {
  size_t pos = 0;
  auto at_end = [&] { return pos >= tokens.size(); };
  auto missing = [&](const std::string& what) {
    const int line = at_end() ? motion_line : tokens[pos].line;
    return invalid_argument_error(line_prefix(line) + "expected " + what + ", found " +
                                  (at_end() ? std::string("MOTION") : quoted(tokens[pos].text)));
  };
  if (at_end() || !equals_ignoring_case(tokens[pos].text, "HIERARCHY")) {
    return missing("HIERARCHY (a BVH file starts with HIERARCHY, then ROOT <name> { ... })");
  }
  ++pos;
  std::set<std::string> names;
  // Reads "<name...> {" after ROOT or JOINT and opens the joint; the name may hold spaces.
  auto open_joint = [&](int parent, std::vector<int>& stack) -> Status {
    const int line = tokens[pos - 1].line;
    std::string name;
    while (!at_end() && tokens[pos].line == line && tokens[pos].text != "{") {
      if (!name.empty()) name += ' ';
      name += tokens[pos].text;
      ++pos;
    }
    if (name.empty()) return invalid_argument_error(line_prefix(line) + "a joint needs a name");
    if (!names.insert(name).second) {
      return invalid_argument_error(line_prefix(line) + "joint \"" + name +
                                    "\" is defined twice; names must be unique");
    }
    if (at_end() || tokens[pos].text != "{") return missing("{ after joint \"" + name + "\"");
    ++pos;
    clip.joints.push_back({name, parent, line, {}, 0, false});
    stack.push_back(static_cast<int>(clip.joints.size()) - 1);
    return ok_status();
  };

  std::vector<int> stack;  // open blocks: joint index, or -1 for an End Site
  bool have_root = false;
  while (!at_end()) {
    const Token token = tokens[pos];
    if (stack.empty()) {
      if (!equals_ignoring_case(token.text, "ROOT")) return missing("ROOT <name> {");
      if (have_root) {
        return invalid_argument_error(line_prefix(token.line) +
                                      "a second ROOT; posewarp reads one skeleton per BVH file");
      }
      have_root = true;
      ++pos;
      POSEWARP_RETURN_IF_ERROR(open_joint(-1, stack));
      continue;
    }
    const int top = stack.back();
    ++pos;
    if (token.text == "}") {
      stack.pop_back();
    } else if (equals_ignoring_case(token.text, "OFFSET")) {
      for (int axis = 0; axis < 3; ++axis) {
        if (at_end()) return missing("three numbers after OFFSET");
        POSEWARP_RETURN_IF_ERROR(parse_number(tokens[pos].text, tokens[pos].line).status());
        ++pos;
      }
    } else if (equals_ignoring_case(token.text, "CHANNELS")) {
      if (top < 0) return invalid_argument_error(line_prefix(token.line) + "an End Site has no CHANNELS");
      BvhJoint& joint = clip.joints[static_cast<size_t>(top)];
      if (joint.has_channels) {
        return invalid_argument_error(line_prefix(token.line) + "joint \"" + joint.name + "\" has two CHANNELS lines");
      }
      if (at_end()) return missing("a channel count after CHANNELS");
      POSEWARP_ASSIGN_OR_RETURN(const int64_t count,
                                parse_count(tokens[pos].text, tokens[pos].line, "the channel count"));
      ++pos;
      if (count > 6) {
        return invalid_argument_error(line_prefix(token.line) + "joint \"" + joint.name + "\" declares " +
                                      std::to_string(count) + " channels; a joint has at most 6");
      }
      for (int64_t c = 0; c < count; ++c) {
        if (at_end() || tokens[pos].line != token.line) {
          return invalid_argument_error(line_prefix(token.line) + "CHANNELS " + std::to_string(count) + " names only " +
                                        std::to_string(c) + " channels; give as many names as the count says");
        }
        POSEWARP_ASSIGN_OR_RETURN(const Channel channel, parse_channel(tokens[pos].text, tokens[pos].line));
        if (std::find(joint.channels.begin(), joint.channels.end(), channel) != joint.channels.end()) {
          return invalid_argument_error(line_prefix(token.line) + "channel \"" + std::string(tokens[pos].text) +
                                        "\" appears twice");
        }
        joint.channels.push_back(channel);
        ++pos;
      }
      if (!at_end() && tokens[pos].line == token.line) {
        return invalid_argument_error(line_prefix(token.line) + "CHANNELS " + std::to_string(count) +
                                      " is followed by more names than that; make the count match the names");
      }
      joint.has_channels = true;
      joint.first_channel = clip.channel_count;
      clip.channel_count += static_cast<int>(count);
    } else if (equals_ignoring_case(token.text, "JOINT")) {
      if (top < 0) return invalid_argument_error(line_prefix(token.line) + "an End Site cannot hold a JOINT");
      POSEWARP_RETURN_IF_ERROR(open_joint(top, stack));
    } else if (equals_ignoring_case(token.text, "End")) {
      if (top < 0) return invalid_argument_error(line_prefix(token.line) + "an End Site cannot hold an End Site");
      if (at_end() || !equals_ignoring_case(tokens[pos].text, "Site")) return missing("Site after End");
      ++pos;
      if (at_end() || tokens[pos].text != "{") return missing("{ after End Site");
      ++pos;
      stack.push_back(-1);
    } else {
      return invalid_argument_error(line_prefix(token.line) + "unexpected \"" + std::string(token.text) +
                                    "\"; expected OFFSET, CHANNELS, JOINT, End Site or }");
    }
  }
  if (!stack.empty()) {
    const std::string open = stack.back() >= 0 ? "joint \"" + clip.joints[static_cast<size_t>(stack.back())].name + "\""
                                               : std::string("an End Site");
    return invalid_argument_error(line_prefix(motion_line) + "MOTION starts before the block of " + open +
                                  " is closed; a } is missing");
  }
  if (!have_root) return invalid_argument_error(line_prefix(motion_line) + "the HIERARCHY has no ROOT");
  if (clip.channel_count == 0) {
    return invalid_argument_error("BVH: the hierarchy declares no CHANNELS, so nothing moves");
  }
  return ok_status();
}

// "Label: value" with the label compared ignoring case and runs of spaces.
bool split_header(std::string_view line, std::string_view label, std::string_view& value) {
  const size_t colon = line.find(':');
  if (colon == std::string_view::npos) return false;
  std::string words;
  std::vector<Token> tokens;
  tokenize(line.substr(0, colon), 0, tokens);
  for (const Token& token : tokens) {
    if (!words.empty()) words += ' ';
    words += token.text;
  }
  if (!equals_ignoring_case(words, label)) return false;
  value = trim(line.substr(colon + 1));
  return true;
}

Result<BvhClip> parse_bvh(const std::string& text) {
  const std::vector<std::string_view> lines = split_lines(text);
  std::vector<Token> tokens;
  size_t motion = lines.size();
  for (size_t i = 0; i < lines.size(); ++i) {
    std::vector<Token> words;
    tokenize(lines[i], static_cast<int>(i) + 1, words);
    if (!words.empty() && equals_ignoring_case(words[0].text, "MOTION")) {
      if (words.size() > 1) {
        return invalid_argument_error(line_prefix(static_cast<int>(i) + 1) + "MOTION must stand on a line of its own");
      }
      motion = i;
      break;
    }
    tokens.insert(tokens.end(), words.begin(), words.end());
  }
  if (motion == lines.size()) {
    return invalid_argument_error(
        "BVH: no MOTION section; a BVH file is HIERARCHY ... then MOTION, Frames:, "
        "Frame Time: and one line of numbers per frame");
  }
  BvhClip clip;
  const int motion_line = static_cast<int>(motion) + 1;
  POSEWARP_RETURN_IF_ERROR(parse_hierarchy(tokens, motion_line, clip));

  size_t i = motion + 1;
  auto next_line = [&]() {
    while (i < lines.size() && trim(lines[i]).empty()) ++i;
    return i < lines.size();
  };
  std::string_view value;
  if (!next_line() || !split_header(lines[i], "Frames", value)) {
    return invalid_argument_error(line_prefix(static_cast<int>(std::min(i, lines.size())) + 1) +
                                  "expected \"Frames: <count>\" after MOTION");
  }
  const int frames_line = static_cast<int>(i) + 1;
  POSEWARP_ASSIGN_OR_RETURN(const int64_t frame_count, parse_count(value, frames_line, "Frames"));
  if (frame_count < 1) return invalid_argument_error(line_prefix(frames_line) + "the clip has no frames to import");
  if (frame_count > std::numeric_limits<int>::max()) {
    return invalid_argument_error(line_prefix(frames_line) + "too many frames (" + std::to_string(frame_count) + ")");
  }
  ++i;
  if (!next_line() || !split_header(lines[i], "Frame Time", value)) {
    return invalid_argument_error(line_prefix(static_cast<int>(std::min(i, lines.size())) + 1) +
                                  "expected \"Frame Time: <seconds>\" after \"Frames:\"");
  }
  POSEWARP_ASSIGN_OR_RETURN(clip.frame_time_s, parse_number(value, static_cast<int>(i) + 1));
  if (!(clip.frame_time_s > 0.0)) {
    return invalid_argument_error(line_prefix(static_cast<int>(i) + 1) + "Frame Time must be positive (seconds)");
  }
  ++i;
  clip.frame_count = static_cast<int>(frame_count);
  // Reserve only what the file can hold, so a lying "Frames:" cannot make us allocate.
  clip.values.reserve(std::min<size_t>(static_cast<size_t>(frame_count), lines.size() - std::min(i, lines.size())) *
                      static_cast<size_t>(clip.channel_count));
  int frames_read = 0;
  std::vector<Token> words;
  while (next_line()) {
    const int line = static_cast<int>(i) + 1;
    if (frames_read == clip.frame_count) {
      return invalid_argument_error(
          line_prefix(line) + "more frame lines than \"Frames: " + std::to_string(clip.frame_count) + "\" (line " +
          std::to_string(frames_line) + ") announces; correct the count or remove the extra lines");
    }
    words.clear();
    tokenize(lines[i], line, words);
    if (words.size() != static_cast<size_t>(clip.channel_count)) {
      return invalid_argument_error(line_prefix(line) + "frame " + std::to_string(frames_read) + " has " +
                                    std::to_string(words.size()) + " values, but the HIERARCHY declares " +
                                    std::to_string(clip.channel_count) + " channels");
    }
    for (const Token& word : words) {
      POSEWARP_ASSIGN_OR_RETURN(const double number, parse_number(word.text, line));
      // No motion capture moves 100 m or turns 28 times in one frame: such a value is damage, and would give an
      // arbitrary rotation.
      if (std::abs(number) > kMaxChannelValue) {
        return invalid_argument_error(line_prefix(line) + "frame " + std::to_string(frames_read) + " holds " +
                                      std::string(word.text) + ", outside [-10000, 10000] (degrees or BVH length " +
                                      "units); the motion is damaged");
      }
      clip.values.push_back(number);
    }
    ++frames_read;
    ++i;
  }
  if (frames_read < clip.frame_count) {
    return invalid_argument_error("BVH line " + std::to_string(lines.size()) + ": the motion is truncated: \"Frames: " +
                                  std::to_string(clip.frame_count) + "\" (line " + std::to_string(frames_line) +
                                  ") but only " + std::to_string(frames_read) + " frame lines follow");
  }
  return clip;
}

// BVH axes -> LPS; see BvhMap::up. Both are proper rotations, so no motion is mirrored.
Eigen::Matrix3d axis_change(char up) {
  Eigen::Matrix3d a = Eigen::Matrix3d::Identity();
  if (up == 'y') a << 1, 0, 0, 0, 0, -1, 0, 1, 0;
  return a;
}

Status check_map(const BvhMap& map) {
  if (map.up != 'y' && map.up != 'z') {
    return invalid_argument_error(std::string("BVH map: up must be 'y' or 'z' (got '") + map.up + "')");
  }
  if (!(map.scale_to_mm > 0.0) || !std::isfinite(map.scale_to_mm)) {
    return invalid_argument_error("BVH map: scale_to_mm must be positive (10 when the BVH is in centimetres)");
  }
  std::map<std::string, std::string> driver_of;
  std::set<std::string> mapped;
  for (const auto& [bvh_joint, rig_joint] : map.joints) {
    if (!mapped.insert(bvh_joint).second) {
      return invalid_argument_error("BVH map: BVH joint \"" + bvh_joint + "\" is mapped twice; map it once");
    }
    const auto [it, inserted] = driver_of.emplace(rig_joint, bvh_joint);
    if (!inserted) {
      return invalid_argument_error("BVH map: rig joint \"" + rig_joint + "\" is driven by two BVH joints (\"" +
                                    it->second + "\" and \"" + bvh_joint + "\"); map one and ignore the other");
    }
  }
  for (const std::string& bvh_joint : map.ignore) {
    if (mapped.count(bvh_joint)) {
      return invalid_argument_error("BVH map: BVH joint \"" + bvh_joint +
                                    "\" is both mapped and ignored; remove it from one of the two");
    }
  }
  return ok_status();
}

std::vector<std::string> rig_joint_names(const rig::Skeleton& skeleton) {
  std::vector<std::string> names;
  for (const rig::Joint& joint : skeleton.joints) names.push_back(joint.name);
  return names;
}

// Checks that every BVH joint is mapped or ignored, every target exists, and the map follows the rig's tree.
// Fills target[k] (rig joint index, or -1 when k is not mapped to a rig joint) and reference[k] (the BVH joint whose
// world rotation k's rotation is taken relative to).
Status match_trees(const BvhClip& clip, const BvhMap& map, const rig::Skeleton& skeleton, bool& root_mapped,
                   std::vector<int>& target, std::vector<int>& reference) {
  std::map<std::string, std::string> target_of(map.joints.begin(), map.joints.end());
  const std::set<std::string> ignored(map.ignore.begin(), map.ignore.end());
  const std::string rig_list = skeleton.joints.empty() ? "(none)" : join(rig_joint_names(skeleton));

  std::vector<std::string> unmapped;
  for (const BvhJoint& joint : clip.joints) {
    if (!target_of.count(joint.name) && !ignored.count(joint.name)) unmapped.push_back("\"" + joint.name + "\"");
  }
  if (!unmapped.empty()) {
    return invalid_argument_error(
        "BVH joints not in the map: " + join(unmapped) +
        ". Add each to the map's \"joints\" as \"<BVH joint>\": " + "\"<rig joint>\" (\"root\" for the BVH root \"" +
        clip.joints[0].name + "\"), or list it in \"ignore\"; the rig's joints are: " + rig_list);
  }
  std::vector<std::string> missing;
  for (const auto& [bvh_joint, rig_joint] : map.joints) {
    if (rig_joint != kBvhRootTarget && skeleton.joint_index(rig_joint) < 0) {
      missing.push_back("\"" + rig_joint + "\" (from \"" + bvh_joint + "\")");
    }
  }
  if (!missing.empty()) {
    return invalid_argument_error("the BVH map drives rig joints the skeleton does not have: " + join(missing) +
                                  ". Change them to rig joints or move their BVH joints to \"ignore\"; the rig's "
                                  "joints are: " +
                                  rig_list);
  }

  const size_t n = clip.joints.size();
  target.assign(n, -1);
  reference.assign(n, 0);
  root_mapped = false;
  for (size_t k = 0; k < n; ++k) {
    const BvhJoint& joint = clip.joints[k];
    const auto it = target_of.find(joint.name);
    if (it == target_of.end()) continue;
    if (k == 0) {
      if (it->second != kBvhRootTarget) {
        return invalid_argument_error("the BVH root \"" + joint.name + "\" is mapped to \"" + it->second +
                                      "\"; the root moves the whole body, so map it to \"root\" or ignore it");
      }
      root_mapped = true;
    } else if (it->second == kBvhRootTarget) {
      return invalid_argument_error("BVH joint \"" + joint.name +
                                    "\" is mapped to \"root\", which only the BVH root \"" + clip.joints[0].name +
                                    "\" may drive; map it to a rig joint or ignore it");
    } else {
      target[k] = skeleton.joint_index(it->second);
    }
  }

  // Rig side: for each joint, the nearest joint above it (towards the root segment) that the map drives.
  std::vector<int> joint_of_child(skeleton.segments.size(), -1);
  for (size_t j = 0; j < skeleton.joints.size(); ++j) {
    const int child = skeleton.joints[j].child;
    if (child >= 0 && static_cast<size_t>(child) < joint_of_child.size())
      joint_of_child[static_cast<size_t>(child)] = static_cast<int>(j);
  }
  std::vector<bool> driven(skeleton.joints.size(), false);
  for (size_t k = 0; k < n; ++k) {
    if (target[k] >= 0) driven[static_cast<size_t>(target[k])] = true;
  }
  auto rig_driven_ancestor = [&](int j) {
    int segment = skeleton.joints[static_cast<size_t>(j)].parent;
    for (size_t steps = 0; steps <= skeleton.joints.size(); ++steps) {
      if (segment < 0 || static_cast<size_t>(segment) >= joint_of_child.size()) return -1;
      const int above = joint_of_child[static_cast<size_t>(segment)];
      if (above < 0 || driven[static_cast<size_t>(above)]) return above;
      segment = skeleton.joints[static_cast<size_t>(above)].parent;
    }
    return -1;
  };
  auto describe_rig = [&](int j) {
    return j < 0 ? std::string("none (the root segment)") : "\"" + skeleton.joints[static_cast<size_t>(j)].name + "\"";
  };

  for (size_t k = 1; k < n; ++k) {
    if (target[k] < 0) continue;
    int a = clip.joints[k].parent;
    while (a > 0 && target[static_cast<size_t>(a)] < 0) a = clip.joints[static_cast<size_t>(a)].parent;
    reference[k] = a;
    const int expected = a > 0 ? target[static_cast<size_t>(a)] : -1;
    const int actual = rig_driven_ancestor(target[k]);
    if (expected != actual) {
      const std::string bvh_above =
          a > 0 ? "\"" + clip.joints[static_cast<size_t>(a)].name + "\", which drives " + describe_rig(expected)
                : "the BVH root, which stands for the rig's root segment";
      return invalid_argument_error("BVH joint \"" + clip.joints[k].name + "\" drives rig joint " +
                                    describe_rig(target[k]) + ", and its nearest mapped BVH ancestor is " + bvh_above +
                                    "; but in the rig the nearest driven joint above " + describe_rig(target[k]) +
                                    " is " + describe_rig(actual) +
                                    ". Change the map so that it follows the rig's tree, or ignore one of the joints");
    }
  }
  return ok_status();
}

Eigen::Matrix3d local_rotation(const BvhJoint& joint, const double* frame_values) {
  constexpr double kRadiansPerDegree = M_PI / 180.0;
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  for (size_t c = 0; c < joint.channels.size(); ++c) {
    const double radians = frame_values[joint.first_channel + static_cast<int>(c)] * kRadiansPerDegree;
    switch (joint.channels[c]) {
      case Channel::kXrotation: r = r * Eigen::AngleAxisd(radians, Eigen::Vector3d::UnitX()).toRotationMatrix(); break;
      case Channel::kYrotation: r = r * Eigen::AngleAxisd(radians, Eigen::Vector3d::UnitY()).toRotationMatrix(); break;
      case Channel::kZrotation: r = r * Eigen::AngleAxisd(radians, Eigen::Vector3d::UnitZ()).toRotationMatrix(); break;
      default: break;
    }
  }
  return r;
}

Eigen::Vector3d root_position(const BvhJoint& root, const double* frame_values) {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (size_t c = 0; c < root.channels.size(); ++c) {
    const double value = frame_values[root.first_channel + static_cast<int>(c)];
    switch (root.channels[c]) {
      case Channel::kXposition: p.x() = value; break;
      case Channel::kYposition: p.y() = value; break;
      case Channel::kZposition: p.z() = value; break;
      default: break;
    }
  }
  return p;
}

}  // namespace

Result<Animation> import_bvh(const std::string& bvh_text, const BvhMap& map, const rig::Skeleton& skeleton, int first,
                             int last) {
  POSEWARP_RETURN_IF_ERROR(check_map(map));
  POSEWARP_ASSIGN_OR_RETURN(const BvhClip clip, parse_bvh(bvh_text));

  bool root_mapped = false;
  std::vector<int> target;
  std::vector<int> reference;
  POSEWARP_RETURN_IF_ERROR(match_trees(clip, map, skeleton, root_mapped, target, reference));

  if (first < 0 || (last != -1 && last < first)) {
    return invalid_argument_error("BVH frame range [" + std::to_string(first) + ", " + std::to_string(last) +
                                  "] is not a range: first must be >= 0 and last >= first, or -1 for the end");
  }
  const int end = last == -1 ? clip.frame_count - 1 : last;
  if (first >= clip.frame_count || end >= clip.frame_count) {
    return out_of_range_error("BVH frame range [" + std::to_string(first) + ", " + std::to_string(last) +
                              "] runs past the clip, which has " + std::to_string(clip.frame_count) + " frames (0 to " +
                              std::to_string(clip.frame_count - 1) + ")");
  }

  const Eigen::Matrix3d a = axis_change(map.up);
  const size_t n = clip.joints.size();
  const size_t channels = static_cast<size_t>(clip.channel_count);
  const Eigen::Vector3d start =
      root_position(clip.joints[0], clip.values.data() + static_cast<size_t>(first) * channels);
  Animation animation;
  animation.frame_time_s = clip.frame_time_s;
  std::vector<Eigen::Matrix3d> world(n);
  for (int f = first; f <= end; ++f) {
    const double* values = clip.values.data() + static_cast<size_t>(f) * channels;
    for (size_t k = 0; k < n; ++k) {
      const Eigen::Matrix3d local = local_rotation(clip.joints[k], values);
      world[k] = k == 0 ? local : world[static_cast<size_t>(clip.joints[k].parent)] * local;
    }
    Pose pose;
    pose.name = "frame " + std::to_string(f);
    if (root_mapped) {
      pose.root.rotation = a * world[0] * a.transpose();
      pose.root.translation = map.scale_to_mm * (a * (root_position(clip.joints[0], values) - start));
    }
    for (size_t k = 1; k < n; ++k) {
      if (target[k] < 0) continue;
      const rig::Joint& joint = skeleton.joints[static_cast<size_t>(target[k])];
      const Eigen::Matrix3d relative = world[static_cast<size_t>(reference[k])].transpose() * world[k];
      const Eigen::Matrix3d lps = a * relative * a.transpose();
      const Eigen::Matrix3d in_frame = joint.frame.transpose() * lps * joint.frame;
      pose.joints.push_back({joint.name, Eigen::Quaterniond(in_frame).normalized()});
    }
    animation.frames.push_back(std::move(pose));
  }
  return animation;
}

Result<Animation> read_bvh(const std::string& path, const BvhMap& map, const rig::Skeleton& skeleton, int first,
                           int last) {
  POSEWARP_ASSIGN_OR_RETURN(const std::string text, detail::read_text_file(path, "BVH file"));
  Result<Animation> animation = import_bvh(text, map, skeleton, first, last);
  if (!animation.ok()) return animation.status().with_context("'" + path + "'");
  return animation;
}

}  // namespace posewarp::pose
