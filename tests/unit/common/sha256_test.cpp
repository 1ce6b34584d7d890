#include "posewarp/common/sha256.h"

#include <gtest/gtest.h>

namespace posewarp {
namespace {

TEST(Sha256, MatchesTheStandardsTestVectors) {
  EXPECT_EQ(sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(sha256_hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(Sha256().update("a").update("bc").hex_digest(), sha256_hex("abc"));  // streamed
}

TEST(Sha256, HexIdsAreCheckedBeforeTheyNameAnything) {
  EXPECT_TRUE(is_hex_id(sha256_hex("x")));
  EXPECT_FALSE(is_hex_id("../../etc/passwd"));
  EXPECT_FALSE(is_hex_id(std::string(63, 'a') + "/"));
  EXPECT_FALSE(is_hex_id(std::string(64, 'A')));  // lowercase only: one spelling per id
  EXPECT_FALSE(is_hex_id(std::string("abc\0def", 7), 7));
}

}  // namespace
}  // namespace posewarp
