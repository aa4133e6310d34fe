// SPDX-License-Identifier: Apache-2.0
// Flags, environment and config file for pliant-server.
#include "pliant/server/options.hpp"

#include "pliant/server/edge.hpp"

#include "cli.hpp"
#include "pliant/version.hpp"

#include <spdlog/fmt/fmt.h>

#include <cstdlib>
#include <fstream>
#include <map>

namespace pliant::server {

namespace {

struct Flag {
  const char* name;  // without "--"
  const char* help;
  std::function<Error(const std::string& value, ServerOptions& o)> set;
};

Error bad(const std::string& flag, const std::string& value, const std::string& rule) {
  return Error::make(Code::InvalidArgument, fmt::format("--{} {}, got {}", flag, rule, echo(value)));
}

Error parse_int(const std::string& flag, const std::string& v, int64_t lo, int64_t hi, int64_t* out) {
  try {
    size_t pos = 0;
    long long x = std::stoll(v, &pos);
    if (pos != v.size() || x < lo || x > hi) throw std::out_of_range("");
    *out = x;
    return {};
  } catch (...) {
    return bad(flag, v, fmt::format("must be an integer in [{}, {}]", lo, hi));
  }
}

// HOST:PORT with a port in [0, 65535] ("[v6]:PORT" too, and "unix:PATH" where allowed).
Error check_listen(const std::string& flag, const std::string& v, bool unix_allowed = true) {
  if (unix_allowed && v.rfind("unix:", 0) == 0) {
    if (v.size() == 5) return bad(flag, v, "needs a socket path after unix:");
    return {};
  }
  const size_t colon = v.rfind(':');
  if (colon == std::string::npos || colon == 0) return bad(flag, v, "must be HOST:PORT");
  const std::string port = v.substr(colon + 1);
  int64_t p = 0;
  if (port.empty() || port.find_first_not_of("0123456789") != std::string::npos ||
      !parse_int(flag, port, 0, 65535, &p).ok())
    return bad(flag, v, "must be HOST:PORT with a port in [0, 65535]");
  return {};
}

// A token travels in an HTTP/2 header: printable ASCII without spaces, 1 to 4096 characters.
Error check_token(const std::string& flag, const std::string& v) {
  if (v.empty() || v.size() > 4096) return bad(flag, "(hidden)", "must hold 1 to 4096 characters");
  for (unsigned char c : v)
    if (c <= 0x20 || c >= 0x7f) return bad(flag, "(hidden)", "must be printable ASCII without spaces");
  return {};
}

Error parse_ms(const std::string& flag, const std::string& v, int64_t* out) {
  return parse_int(flag, v, 0, 86'400'000, out);
}

// The setter of a flag that takes an integer in [lo, hi] into `field`.
template <class T>
std::function<Error(const std::string&, ServerOptions&)> integer(const char* flag, int64_t lo, int64_t hi,
                                                                 T ServerOptions::*field) {
  return [=](const std::string& v, ServerOptions& o) {
    int64_t x = 0;
    if (Error e = parse_int(flag, v, lo, hi, &x); !e.ok()) return e;
    o.*field = static_cast<T>(x);
    return Error{};
  };
}

const std::vector<Flag>& flags() {
  static const std::vector<Flag> f = {
      {"listen", "HOST:PORT to listen on (default 0.0.0.0:50051; port 0 picks a free port)",
       [](const std::string& v, ServerOptions& o) {
         if (Error e = check_listen("listen", v); !e.ok()) return e;
         o.listen = v;
         return Error{};
       }},
      {"data-dir", "directory for snapshots; scenes are saved there on shutdown and restored on start",
       [](const std::string& v, ServerOptions& o) { o.data_dir = v; return Error{}; }},
      {"model-path", "colon-separated directories searched for mesh files and model names "
                     "(MeshSource.model_path; default: $PLIANT_MODEL_PATH, then <prefix>/share/pliant/meshes "
                     "for an installed server, else the source tree's meshes/)",
       [](const std::string& v, ServerOptions& o) { o.model_path = v; return Error{}; }},
      {"max-scenes", "most scenes hosted at once (default 16)",
       integer("max-scenes", 1, 100000, &ServerOptions::max_scenes)},
      {"max-vertices", "most vertices in one scene's mesh (default 2000000)",
       integer("max-vertices", 4, 1'000'000'000, &ServerOptions::max_vertices)},
      {"max-message-mb", "largest request or response message, MiB (default 64)",
       integer("max-message-mb", 1, 2000, &ServerOptions::max_message_mb)},
      {"log-level", "trace | debug | info | warn | error | critical | off (default info)",
       [](const std::string& v, ServerOptions& o) {
         static const char* levels[] = {"trace", "debug", "info", "warn", "error", "critical", "off"};
         for (const char* l : levels)
           if (v == l) {
             o.log_level = v;
             return Error{};
           }
         return bad("log-level", v, "must be one of trace, debug, info, warn, error, critical, off");
       }},
      {"tls-cert", "PEM certificate chain; with --tls-key the server speaks TLS",
       [](const std::string& v, ServerOptions& o) { o.tls_cert = v; return Error{}; }},
      {"tls-key", "PEM private key for --tls-cert",
       [](const std::string& v, ServerOptions& o) { o.tls_key = v; return Error{}; }},
      {"token", "access token clients must send as 'authorization: Bearer TOKEN' (visible in the process "
                "list: prefer --token-file or PLIANT_TOKEN)",
       [](const std::string& v, ServerOptions& o) {
         if (Error e = check_token("token", v); !e.ok()) return e;
         o.token = v;
         return Error{};
       }},
      {"token-file", "file holding the access token (one line; wins over --token)",
       [](const std::string& v, ServerOptions& o) {
         std::ifstream f(v, std::ios::binary);
         std::string line;
         if (!f || !std::getline(f, line)) return bad("token-file", v, "must be a readable file holding the token");
         if (!line.empty() && line.back() == '\r') line.pop_back();
         if (Error e = check_token("token-file", line); !e.ok())
           return bad("token-file", v, "must hold the token on its first line (printable ASCII, no spaces)");
         o.token_file_token = line;
         return Error{};
       }},
      {"reflection", "open | token | off: gRPC reflection without the token (default open), only with it, or not "
                     "served",
       [](const std::string& v, ServerOptions& o) {
         if (v != "open" && v != "token" && v != "off") return bad("reflection", v, "must be open, token or off");
         o.reflection = v;
         return Error{};
       }},
      {"max-tick-ms", "a tick whose solver runs longer is stopped, undone and its scene paused (default 10000; "
                      "0: no limit)",
       [](const std::string& v, ServerOptions& o) { return parse_ms("max-tick-ms", v, &o.max_tick_ms); }},
      {"stuck-tick-ms", "health is NOT_SERVING while a tick has run longer than this (default 15000; 0: never)",
       [](const std::string& v, ServerOptions& o) { return parse_ms("stuck-tick-ms", v, &o.stuck_tick_ms); }},
      {"max-streams", "most open StreamFrames + HapticStream calls (default 256)",
       integer("max-streams", 1, 100000, &ServerOptions::max_streams)},
      {"max-streams-per-scene", "most open streams on one scene (default 64)",
       integer("max-streams-per-scene", 1, 100000, &ServerOptions::max_streams_per_scene)},
      {"max-grabs-per-scene", "most grabs held on one scene at once (default 64)",
       integer("max-grabs-per-scene", 1, 100000, &ServerOptions::max_grabs_per_scene)},
      {"checkpoint-ms", "scenes that changed are saved to --data-dir this often (default 5000; 0: only at "
                        "shutdown)",
       [](const std::string& v, ServerOptions& o) {
         if (Error e = parse_ms("checkpoint-ms", v, &o.checkpoint_ms); !e.ok()) return e;
         if (o.checkpoint_ms > 0 && o.checkpoint_ms < 100) return bad("checkpoint-ms", v, "must be 0 or at least 100");
         return Error{};
       }},
      {"threads", "most solver threads one scene may use (default 1)",
       integer("threads", 1, 256, &ServerOptions::threads)},
      {"restore", "true | false: restore the scenes saved in --data-dir on start (default true)",
       [](const std::string& v, ServerOptions& o) {
         if (v == "true" || v == "1" || v == "yes") o.restore = true;
         else if (v == "false" || v == "0" || v == "no") o.restore = false;
         else return bad("restore", v, "must be true or false");
         return Error{};
       }},
      {"metrics-listen", "HOST:PORT of a Prometheus /metrics endpoint over HTTP (default: none; e.g. "
                         "127.0.0.1:9464; numeric address or localhost; port 0 picks a free port)",
       [](const std::string& v, ServerOptions& o) {
         if (Error e = check_listen("metrics-listen", v, false); !e.ok()) return e;
         o.metrics_listen = v;
         return Error{};
       }},
  };
  return f;
}

const Flag* find_flag(const std::string& name) {
  for (const auto& f : flags())
    if (name == f.name) return &f;
  return nullptr;
}

std::string env_name(const std::string& flag) {
  std::string s = "PLIANT_";
  for (char c : flag) s += c == '-' ? '_' : static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

std::string trim(const std::string& s) {
  size_t a = s.find_first_not_of(" \t\r\n"), b = s.find_last_not_of(" \t\r\n");
  return a == std::string::npos ? "" : s.substr(a, b - a + 1);
}

}  // namespace

EnvLookup process_env() {
  return [](const std::string& name) -> std::optional<std::string> {
    if (const char* v = std::getenv(name.c_str())) return std::string(v);
    return std::nullopt;
  };
}

std::string server_usage() {
  std::string s =
      "usage: pliant-server [--flag value | --flag=value]...\n"
      "Hosts Pliant soft-body scenes over gRPC (pliant.v1, grpc.health.v1, reflection).\n\n";
  for (const auto& f : flags()) s += fmt::format("  --{:<16} {}\n", f.name, f.help);
  s += fmt::format("  --{:<16} {}\n", "no-restore", "same as --restore=false");
  s += fmt::format("  --{:<16} {}\n", "config FILE", "read 'name = value' lines (flag names without --)");
  s += fmt::format("  --{:<16} {}\n", "help", "this text");
  s += fmt::format("  --{:<16} {}\n", "version", "print the version and exit");
  s += "\nEvery flag can also be set as PLIANT_<NAME> in the environment (e.g. PLIANT_LISTEN,\n"
       "PLIANT_DATA_DIR, PLIANT_TOKEN); flags win over the environment, the environment over\n"
       "the config file (PLIANT_CONFIG).\n";
  return s;
}

Error parse_server_options(const std::vector<std::string>& args, const EnvLookup& env,
                           ServerOptions* out, bool* help, bool* version) {
  *help = false;
  if (version) *version = false;
  // CLI11 splits the arguments ("--flag value", "--flag=value"); the flags are collected first
  // and applied after the config file (named by a flag or the environment) and the
  // environment, each through its own check.
  std::vector<std::pair<std::string, std::string>> given;
  CLI::App app{"pliant-server"};
  app.set_help_flag("-h,--help");
  app.set_version_flag("--version", std::string(kVersion));
  app.allow_extras(true);
  auto collect = [&given](const std::string& name) {
    return [&given, name](const std::string& v) { given.emplace_back(name, v); };
  };
  for (const auto& f : flags())
    app.add_option_function<std::string>(std::string("--") + f.name, collect(f.name), f.help)
        ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  app.add_option_function<std::string>("--config", collect("config"), "read 'name = value' lines")
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  app.add_flag_callback("--no-restore", [&given] { given.emplace_back("restore", "false"); });
  std::vector<std::string> reversed(args.rbegin(), args.rend());  // CLI11 takes a vector in reverse
  try {
    app.parse(reversed);
  } catch (const CLI::CallForHelp&) {
    *help = true;
    return {};
  } catch (const CLI::CallForVersion&) {
    if (version) *version = true;
    else *help = true;
    return {};
  } catch (const CLI::ParseError& e) {
    return Error::make(Code::InvalidArgument, fmt::format("{} (see --help)", pliant::cli::one_line(e.what())));
  }
  for (const std::string& a : app.remaining()) {
    if (a.rfind("--", 0) == 0)
      return Error::make(Code::InvalidArgument,
                         fmt::format("unknown flag --{} (see --help)", a.substr(2, a.find('=') - 2)));
    return Error::make(Code::InvalidArgument, fmt::format("unexpected argument '{}' (flags start with --)", a));
  }

  ServerOptions o;
  std::string config_file;
  if (auto v = env("PLIANT_CONFIG")) config_file = *v;
  for (auto& [n, v] : given)
    if (n == "config") config_file = v;
  if (!config_file.empty()) {
    std::ifstream f(config_file);
    if (!f) return Error::make(Code::InvalidArgument, fmt::format("--config '{}' cannot be read", config_file));
    std::string line;
    for (int lineno = 1; std::getline(f, line); ++lineno) {
      line = trim(line.substr(0, line.find('#')));
      if (line.empty()) continue;
      auto eq = line.find('=');
      if (eq == std::string::npos)
        return Error::make(Code::InvalidArgument,
                           fmt::format("{}:{}: expected 'name = value', got '{}'", config_file, lineno, line));
      std::string name = trim(line.substr(0, eq)), value = trim(line.substr(eq + 1));
      if (name.rfind("--", 0) == 0) name = name.substr(2);
      const Flag* flag = find_flag(name);
      if (!flag)
        return Error::make(Code::InvalidArgument, fmt::format("{}:{}: unknown setting '{}'", config_file, lineno, name));
      if (Error e = flag->set(value, o); !e.ok()) {
        e.message = fmt::format("{}:{}: {}", config_file, lineno, e.message);
        return e;
      }
    }
    o.config = config_file;
  }
  for (const auto& f : flags()) {
    if (auto v = env(env_name(f.name))) {
      if (Error e = f.set(*v, o); !e.ok()) {
        e.message = fmt::format("{} (from {})", e.message, env_name(f.name));
        return e;
      }
    }
  }
  for (auto& [n, v] : given) {
    if (n == "config") continue;
    if (Error e = find_flag(n)->set(v, o); !e.ok()) return e;
  }
  if (!o.token_file_token.empty()) o.token = o.token_file_token;
  if (o.reflection == "token" && o.token.empty())
    return Error::make(Code::InvalidArgument, "--reflection token needs a token (--token-file, PLIANT_TOKEN or --token)");
  if (o.tls_cert.empty() != o.tls_key.empty())
    return Error::make(Code::InvalidArgument, "--tls-cert and --tls-key must be given together");
  *out = std::move(o);
  return {};
}

}  // namespace pliant::server
