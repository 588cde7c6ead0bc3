// Report building blocks: base64 against RFC 4648 test vectors, the SVG chart geometry, the colour
// map's end points. (The log.jsonl reader is tested in tests/run/run_log_test.cpp.)
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "eval/colormap.h"
#include "eval/report.h"

using namespace ablenerf;

TEST(Base64, Rfc4648Vectors) {
  EXPECT_EQ(base64_encode(""), "");
  EXPECT_EQ(base64_encode("f"), "Zg==");
  EXPECT_EQ(base64_encode("fo"), "Zm8=");
  EXPECT_EQ(base64_encode("foo"), "Zm9v");
  EXPECT_EQ(base64_encode("foob"), "Zm9vYg==");
  EXPECT_EQ(base64_encode("fooba"), "Zm9vYmE=");
  EXPECT_EQ(base64_encode("foobar"), "Zm9vYmFy");
  // High bytes (a PNG signature): 89 50 4E 47 0D 0A 1A 0A.
  EXPECT_EQ(base64_encode(std::string("\x89PNG\r\n\x1a\n", 8)), "iVBORw0KGgo=");
}

TEST(SvgChart, PolylineSpansThePlotAreaAndLogAxisHasDecades) {
  ChartSeries s{"loss", "#f00", {0, 50, 100}, {1.0, 0.1, 0.01}, false};
  const std::string svg = svg_chart("t", "step", "loss", {s}, true, 400, 200);
  EXPECT_EQ(svg.rfind("<svg", 0), 0u);
  // Three points in a polyline; a log axis from 0.01 to 1 labels the decades 0.01, 0.1, 1.
  const auto poly = svg.find("<polyline");
  ASSERT_NE(poly, std::string::npos);
  for (const char* label : {">0.01<", ">0.1<", ">1<"}) EXPECT_NE(svg.find(label), std::string::npos) << label;
  // Log-spaced values equally spaced in log: the middle point sits at the middle height.
  // Plot area: top 28, height 200 - 28 - 44 = 128 -> y of 0.1 is 28 + 64 = 92.
  EXPECT_NE(svg.find("92.0", poly), std::string::npos) << svg.substr(poly, 200);
  // Non-positive values are dropped on a log axis, and an empty chart says so.
  ChartSeries bad{"x", "#000", {1}, {0.0}, false};
  EXPECT_NE(svg_chart("t", "s", "y", {bad}, true).find("no data"), std::string::npos);
}

TEST(HtmlEscape, EscapesMarkup) { EXPECT_EQ(html_escape("a<b>&\"c"), "a&lt;b&gt;&amp;&quot;c"); }

TEST(Colormap, EndPointsAreViridisAndClamped) {
  const auto v = torch::tensor({{-1.0f, 0.0f, 2.0f, 4.0f, 9.0f}});
  const auto c = colormap(v, 0.0, 4.0);
  ASSERT_EQ(c.sizes(), (std::vector<int64_t>{1, 5, 3}));
  // Below the range = first stop (dark purple), above = last (yellow); the middle is the
  // middle stop (teal, 0.128 0.567 0.551).
  EXPECT_TRUE(torch::allclose(c[0][0], torch::tensor({0.267f, 0.005f, 0.329f}), 0, 1e-6));
  EXPECT_TRUE(torch::allclose(c[0][1], c[0][0]));
  EXPECT_TRUE(torch::allclose(c[0][2], torch::tensor({0.128f, 0.567f, 0.551f}), 0, 1e-6));
  EXPECT_TRUE(torch::allclose(c[0][3], torch::tensor({0.993f, 0.906f, 0.144f}), 0, 1e-6));
  EXPECT_TRUE(torch::allclose(c[0][4], c[0][3]));
}
