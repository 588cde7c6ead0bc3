// The run configuration's schema: TOML and --set reach every key, names of enum values come from
// one table per enum, and every kind of bad input names the file and the key.
#include <gtest/gtest.h>

#include <set>
#include <string>
#include <vector>

#include "data/data_config.h"
#include "eval/eval_config.h"
#include "model/compute_config.h"
#include "model/model_config.h"
#include "train/train_config.h"
#include "util/config.h"
#include "util/errors.h"

using namespace ablenerf;

namespace {

// The message of the InputError that `f` throws ("" when it throws none).
template <class F>
std::string input_error(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// Every value of an enum's table parses back to itself and prints as its name, through TOML
// and through --set, for the key `key`.
template <class E>
void expect_names_round_trip(const std::string& key) {
  for (const auto& [value, name] : enum_names<E>()) {
    Config c;
    c.set(key + "=" + name);  // bare, as on the command line
    const Config back = Config::parse(c.to_toml(), "round-trip");
    EXPECT_EQ(back.items(), c.items()) << key << " = " << name;
    bool found = false;
    for (const auto& [k, v] : back.items())
      if (k == key) {
        EXPECT_EQ(v, std::string("\"") + name + "\"");
        found = true;
      }
    EXPECT_TRUE(found) << key;
  }
}

}  // namespace

TEST(Config, EnumKeysTakeEveryNameOfTheirTable) {
  expect_names_round_trip<ViewEncoding>("model.view_encoding");
  expect_names_round_trip<Background>("data.background");
  expect_names_round_trip<SsimVariant>("eval.ssim");
  expect_names_round_trip<AttentionKernel>("compute.attention");
  expect_names_round_trip<Precision>("compute.precision");
  expect_names_round_trip<CpuSplit>("compute.cpu_split");
  expect_names_round_trip<Embedding>("model.embedding");
  expect_names_round_trip<SceneKind>("data.scene");
  expect_names_round_trip<MaskSource>("data.masks");
  expect_names_round_trip<RaySampling>("train.ray_sampling");

  Config c;
  c.set("data.background=black");
  c.set("model.view_encoding=\"paper\"");  // quoted works too
  c.set("eval.ssim=release");
  EXPECT_EQ(c.get<DataConfig>().background, Background::Black);
  EXPECT_EQ(c.get<ModelConfig>().view_encoding, ViewEncoding::Paper);
  EXPECT_EQ(c.get<EvalConfig>().ssim, SsimVariant::Release);
}

TEST(Config, NameTablesAreOneToOne) {
  auto check = [](const auto& table) {
    for (size_t i = 0; i < table.size(); ++i)
      for (size_t j = i + 1; j < table.size(); ++j) {
        EXPECT_NE(table[i].first, table[j].first);
        EXPECT_STRNE(table[i].second, table[j].second);
      }
    for (const auto& [v, n] : table) {
      EXPECT_STREQ(name_of(v), n);
      EXPECT_EQ(enum_from_name<std::decay_t<decltype(v)>>(n), v);
    }
  };
  check(enum_names<ViewEncoding>());
  check(enum_names<Background>());
  check(enum_names<SsimVariant>());
  check(enum_names<AttentionKernel>());
  check(enum_names<Precision>());
  check(enum_names<CpuSplit>());
  check(enum_names<Embedding>());
  check(enum_names<SceneKind>());
  check(enum_names<MaskSource>());
  check(enum_names<RaySampling>());
  EXPECT_FALSE(enum_from_name<Background>("White").has_value());  // names are exact
}

TEST(Config, AnUnknownNameListsTheAllowedOnes) {
  EXPECT_EQ(input_error([] { Config::parse("[data]\nbackground = \"grey\"\n", "a.toml"); }),
            "a.toml: data.background: must be \"white\" or \"black\"");
  EXPECT_EQ(input_error([] {
              Config c;
              c.set("model.view_encoding=octaves");
            }),
            "--set: model.view_encoding: must be \"release\" or \"paper\"");
  EXPECT_EQ(input_error([] { Config::parse("[eval]\nssim = 3\n", "b.toml"); }),
            "b.toml: eval.ssim: must be \"standard\" or \"release\"");
}

TEST(Config, BadInputNamesFileAndKey) {
  EXPECT_EQ(input_error([] { Config::parse("[model]\nwidth = \"wide\"\n", "c.toml"); }),
            "c.toml: model.width: expected an integer");
  EXPECT_EQ(input_error([] { Config::parse("[model]\nwidht = 4\n", "c.toml"); }).rfind("c.toml: model.widht", 0), 0u);
  EXPECT_EQ(input_error([] { Config::parse("[model]\nwidth = 5000000000\n", "c.toml"); }),
            "c.toml: model.width: out of range");
  EXPECT_EQ(input_error([] {
              Config c;
              c.set("train.steps");
            }).rfind("--set: train.steps", 0),
            0u);
  EXPECT_EQ(input_error([] {
              Config c;
              c.set("train.stepz=3");
            }),
            "--set: train.stepz: unknown key");
  EXPECT_EQ(input_error([] { Config::parse("[train]\nlr_init = nan\n", "d.toml"); }),
            "d.toml: train.lr_init: must be finite");
  EXPECT_EQ(input_error([] { Config::parse("[train]\nadam_beta2 = 1.0\n", "e.toml").validate(); }),
            "e.toml: train.adam_beta2: must be in [0, 1)");
  EXPECT_EQ(input_error([] { Config::parse("[train]\nadam_eps = 0.0\n", "e.toml").validate(); }),
            "e.toml: train.adam_eps: must be > 0");
}

TEST(Config, ResolvedTomlReproducesEveryKey) {
  Config c;
  c.set("model.width=64");
  c.set("train.lr_init=0.00123");
  c.set("model.mask=false");
  c.set("data.background=black");
  const Config back = Config::parse(c.to_toml(), "resolved");
  EXPECT_EQ(back.items(), c.items());
  EXPECT_EQ(back.get<ModelConfig>().width, 64);
  EXPECT_DOUBLE_EQ(back.get<TrainConfig>().lr_init, 0.00123);
  EXPECT_FALSE(back.get<ModelConfig>().mask);
  // Every key of the schema is written.
  const std::string toml = c.to_toml();
  for (const auto& [key, value] : c.items()) {
    const std::string leaf = key.substr(key.find('.') + 1);
    EXPECT_NE(toml.find(leaf + " = "), std::string::npos) << key;
  }
}

// Each section (owned by its module: util/config_section.h) lists its keys once, under its own
// name, in the order config.toml writes them, and its checks report the key with the section's name.
TEST(Config, SectionsListTheirKeysOnceUnderTheirName) {
  const Config c;
  std::vector<std::string> sections;
  std::set<std::string> keys;
  for (const auto& [key, value] : c.items()) {
    EXPECT_TRUE(keys.insert(key).second) << key << " listed twice";
    const std::string sec = key.substr(0, key.find('.'));
    if (sections.empty() || sections.back() != sec) sections.push_back(sec);
  }
  EXPECT_EQ(sections, (std::vector<std::string>{"model", "data", "train", "eval", "compute"}));
  EXPECT_TRUE(keys.count("model.proposal_samples") && keys.count("data.masks") && keys.count("train.graph") &&
              keys.count("eval.ssim") && keys.count("compute.cpu_split"));
  EXPECT_EQ(input_error([] { Config::parse("[data]\ndownscale = -1\n", "f.toml").validate(); }),
            "f.toml: data.downscale: must be >= 1, or 0 to choose from the capture");
  EXPECT_EQ(input_error([] { Config::parse("[data]\ndownscale = 0\n", "f.toml").validate(); }), "");
  EXPECT_EQ(input_error([] { Config::parse("[eval]\nchunk = 0\n", "f.toml").validate(); }),
            "f.toml: eval.chunk: must be >= 1");
  EXPECT_EQ(input_error([] { Config::parse("[model]\nheads = 5\n", "f.toml").validate(); }),
            "f.toml: model.heads: must divide model.width");
  EXPECT_EQ(input_error([] { Config::parse("[train]\nerror_tile = 300\n", "f.toml").validate(); }),
            "f.toml: train.error_tile: must be in 1..256 pixels");
  EXPECT_NO_THROW(Config().validate());
}

// A Config owns its sections: a copy is independent of the original, and a type that no header
// registered as a section is a programming error, not a default.
TEST(Config, CopiesOwnTheirSectionsAndUnknownTypesAreRefused) {
  Config a;
  a.set("model.width=64");
  Config b = a;
  b.set("model.width=32");
  EXPECT_EQ(a.get<ModelConfig>().width, 64);
  EXPECT_EQ(b.get<ModelConfig>().width, 32);
  a = b;
  b.get<ModelConfig>().width = 16;
  EXPECT_EQ(a.get<ModelConfig>().width, 32);
  struct NotASection {};
  EXPECT_THROW(Config().get<NotASection>(), std::logic_error);
}
