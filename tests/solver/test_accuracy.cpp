// SPDX-License-Identifier: Apache-2.0
// The accuracy figure of merit: method specs parse as documented (and bad ones are named), and
// `pliant-sim accuracy` on beam1 with a small budget writes one CSV per spec whose true error
// falls with the milliseconds spent, a JSON last line with ms_to_error per method, and reports a
// refused method without stopping the others. `pliant-sim cloth --csv` traces every step and
// agrees with its JSON summary.
#include "pliant/accuracy.hpp"

#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

using namespace pliant;

namespace {

struct ToolRun {
  int status = -1;
  std::string out;
};

ToolRun run_sim(const std::string& args) {
  const std::string cmd = std::string(PLIANT_SIM_TOOL) + " " + args + " 2>/dev/null";
  ToolRun r;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  const int st = ::pclose(p);
  r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

std::string last_line(const std::string& s) {
  std::string t = s;
  while (!t.empty() && t.back() == '\n') t.pop_back();
  const size_t nl = t.rfind('\n');
  return nl == std::string::npos ? t : t.substr(nl + 1);
}

// The JSON object of the method whose spec is `spec` (methods are flat apart from ms_to_error).
std::string method_object(const std::string& json, const std::string& spec) {
  const size_t at = json.find("{\"spec\":\"" + spec + "\"");
  if (at == std::string::npos) return "";
  int depth = 0;
  for (size_t i = at; i < json.size(); ++i) {
    if (json[i] == '{') ++depth;
    if (json[i] == '}' && --depth == 0) return json.substr(at, i + 1 - at);
  }
  return "";
}

// The number after "key": in a one-line JSON object (-1 and a failure when the key is missing).
double json_number(const std::string& json, const std::string& key) {
  const size_t at = json.find("\"" + key + "\":");
  EXPECT_NE(at, std::string::npos) << key;
  return at == std::string::npos ? -1.0 : std::stod(json.substr(at + key.size() + 3));
}

// pliant-sim `args` with --csv to a temporary file: its exit status, its last stdout line (the
// JSON summary), the CSV's header and each line's numbers, checked to be `columns` wide and to
// start with the step (1, 2, ...) and its time at 60 Hz.
struct CsvRun {
  int status = -1;
  std::string json, header;
  std::vector<std::vector<double>> rows;
};
CsvRun run_with_csv(const std::string& args, size_t columns) {
  const std::filesystem::path csv =
      std::filesystem::temp_directory_path() / ("pliant_sim_" + std::to_string(::getpid()) + ".csv");
  const ToolRun r = run_sim(args + " --csv " + csv.string());
  CsvRun out;
  out.status = r.status;
  out.json = last_line(r.out);
  std::ifstream in(csv);
  if (std::getline(in, out.header))
    for (std::string line; std::getline(in, line);) {
      std::vector<double> v;
      std::stringstream ss(line);
      for (std::string cell; std::getline(ss, cell, ',');) v.push_back(std::stod(cell));
      EXPECT_EQ(v.size(), columns) << line;
      v.resize(columns);
      EXPECT_EQ(v[0], double(out.rows.size() + 1)) << line;
      EXPECT_NEAR(v[1], double(out.rows.size() + 1) / 60.0, 1e-6) << line;
      out.rows.push_back(std::move(v));
    }
  std::filesystem::remove(csv);
  return out;
}

struct Row {
  double ms, error;
};

std::vector<Row> read_csv(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);  // header
  std::vector<Row> rows;
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::string f[5];
    for (auto& x : f) std::getline(ss, x, ',');
    rows.push_back({std::stod(f[0]), std::stod(f[3])});
  }
  return rows;
}

}  // namespace

TEST(AccuracySpec, ParsesBudgetsAndKeys) {
  const SolverSettings base;
  const MethodSpec fixed = parse_method_spec("xpbd:64x1", base);
  EXPECT_FALSE(fixed.grows());
  EXPECT_EQ(fixed.settings.substeps, 64);
  EXPECT_EQ(fixed.settings.iterations, 1);
  const MethodSpec a = parse_method_spec("anderson-sor:1xN:omega=3:window=7:sweep=sequential", base);
  EXPECT_TRUE(a.iterations_grow);
  EXPECT_FALSE(a.substeps_grow);
  EXPECT_EQ(a.settings.method, Method::AndersonSor);
  EXPECT_DOUBLE_EQ(a.settings.omega, 3.0);
  EXPECT_EQ(a.settings.window, 7);
  EXPECT_EQ(a.settings.sweep, Sweep::Sequential);
  EXPECT_DOUBLE_EQ(parse_method_spec("anderson-sor:1xN", base).settings.omega, 2.0);  // recommended
  EXPECT_TRUE(parse_method_spec("xpbd:Nx1", base).substeps_grow);
  EXPECT_EQ(parse_method_specs("xpbd:64x1, xpbd:1xN", base).size(), 2u);
  for (const char* bad : {"xpbd", "foo:1x1", "xpbd:NxN", "xpbd:0x1", "xpbd:1x1:bogus=1", "xpbd:1x1:omega=abc", "xpbd:4"}) {
    try {
      parse_method_spec(bad, base);
      ADD_FAILURE() << bad << " was accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(bad), std::string::npos) << e.what();
    }
  }
}

TEST(AccuracySpec, MsToErrorIsTheFirstTimeTheErrorIsReached) {
  AccuracyCurve c;
  c.points = {{1, 1, 1, 0.5, 0}, {2, 2, 1, 0.05, 0}, {3, 3, 1, 0.02, 0}, {4, 4, 1, 0.008, 0}};
  EXPECT_DOUBLE_EQ(*ms_to_error(c, 1e-1), 2.0);
  EXPECT_DOUBLE_EQ(*ms_to_error(c, 1e-2), 4.0);
  EXPECT_FALSE(ms_to_error(c, 1e-3).has_value());
}

TEST(AccuracyCommand, Beam1ErrorFallsWithTimeAndEveryMethodIsReported) {
  const auto dir = std::filesystem::temp_directory_path() / ("pliant-accuracy-test-" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  // The last spec asks for the one-thread sweep with two threads: refused, the others still run.
  // The budget leaves room for several points per spec on a loaded machine (40 ms did not).
  const ToolRun r = run_sim("accuracy --mesh beam1 --young 1e5 --budget-ms 200 --threads 2 --csv-dir " + dir.string() +
                            " --methods xpbd:1xN,xpbd:4xN,xpbd:8x2,xpbd:1xN:sweep=sequential");
  ASSERT_EQ(r.status, 0) << r.out;
  const std::string json = last_line(r.out);
  ASSERT_EQ(json.front(), '{');
  ASSERT_EQ(json.back(), '}');
  for (const char* spec : {"xpbd:1xN", "xpbd:4xN", "xpbd:8x2", "xpbd:1xN:sweep=sequential"}) {
    const std::string m = method_object(json, spec);
    ASSERT_FALSE(m.empty()) << spec << " missing in " << json;
    for (const char* key : {"\"ms_to_error\":{\"1e-1\":", "\"1e-2\":", "\"1e-3\":", "\"error_final\":"})
      EXPECT_NE(m.find(key), std::string::npos) << spec << ": no " << key << " in " << m;
  }
  EXPECT_NE(method_object(json, "xpbd:1xN:sweep=sequential").find("\"refused\":\"solver.threads"), std::string::npos);
  EXPECT_NE(method_object(json, "xpbd:1xN").find("\"refused\":null"), std::string::npos);

  // One point per iteration, time increasing, and more time buys a smaller true error.
  const auto rows = read_csv((dir / "xpbd_1xN.csv").string());
  ASSERT_GE(rows.size(), 5u);
  for (size_t i = 1; i < rows.size(); ++i) EXPECT_GE(rows[i].ms, rows[i - 1].ms);
  EXPECT_LT(rows.back().error, 0.9 * rows.front().error);
  EXPECT_LT(rows.back().error, 1.0);
  const auto grown = read_csv((dir / "xpbd_4xN.csv").string());
  ASSERT_GE(grown.size(), 2u);
  EXPECT_LT(grown.back().error, grown.front().error);
  EXPECT_TRUE(std::filesystem::exists(dir / "true_error_vs_ms.png"));
  std::filesystem::remove_all(dir);
}

TEST(AccuracyCommand, BadSpecIsAUsageError) {
  const ToolRun r = run_sim("accuracy --mesh beam1 --methods xpbd:0x1 --budget-ms 5");
  EXPECT_EQ(r.status, 2);
}

TEST(ClothCommand, CsvTracesEveryStepAndAgreesWithTheSummary) {
  const CsvRun r = run_with_csv("cloth --grid 16 --size 0.2 --drape sphere --radius 0.05 --seconds 0.25 --substeps 8", 9);
  ASSERT_EQ(r.status, 0) << r.json;
  EXPECT_EQ(r.header, "step,t_s,ms,max_stretch,rms_stretch,max_speed_m_s,self_contacts,collider_contacts,min_clearance_m");
  ASSERT_EQ(r.rows.size(), 15u);
  double max_stretch = 0, max_speed = 0, min_clearance = 1e300;
  for (const std::vector<double>& v : r.rows) {
    max_stretch = std::max(max_stretch, v[3]);
    max_speed = std::max(max_speed, v[5]);
    min_clearance = std::min(min_clearance, v[8]);
  }
  EXPECT_NEAR(max_stretch, json_number(r.json, "max_stretch"), 1e-5 * std::max(1.0, max_stretch));
  EXPECT_NEAR(max_speed, json_number(r.json, "max_speed"), 1e-5 * max_speed);
  EXPECT_NEAR(min_clearance, json_number(r.json, "min_clearance_m"), 1e-8);
  EXPECT_GT(max_speed, 0.5) << "the cloth falls onto the sphere";
}

TEST(FluidCommand, CsvTracesEveryStepAndAgreesWithTheSummary) {
  const CsvRun r = run_with_csv(
      "fluid --scene dam-break --particles 500 --substeps 2 --iterations 2 --seconds 0.25 --threads 1 --quiet", 7);
  ASSERT_EQ(r.status, 0) << r.json;
  EXPECT_EQ(r.header, "step,t_s,ms,density_error_mean,density_error_max,contacts,particles");
  ASSERT_EQ(r.rows.size(), 15u);
  // The summary's window: the last quarter of the steps (--settled-after 0.75), here the last 4.
  double ms = 0, error_sum = 0, error_max = 0;
  for (size_t k = 0; k < r.rows.size(); ++k) {
    const std::vector<double>& v = r.rows[k];
    EXPECT_EQ(v[6], json_number(r.json, "particles"));
    ms += v[2];
    if (k >= 11) {
      error_sum += v[3];
      error_max = std::max(error_max, v[4]);
    }
  }
  const double mean_error = json_number(r.json, "mean_density_error");
  EXPECT_NEAR(ms / 15.0, json_number(r.json, "ms_per_step_mean"), 1e-3);
  EXPECT_NEAR(error_sum / 4.0, mean_error, 1e-5 * mean_error + 1e-12);
  EXPECT_NEAR(error_max, json_number(r.json, "max_density_error"), 1e-5 * error_max + 1e-12);
  EXPECT_GT(error_max, 0.0) << "the block falls and is compressed";
  EXPECT_GT(r.rows.back()[5], 0.0) << "the container holds it";
}
