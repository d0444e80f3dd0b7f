// The C++ half of bench/dynamics_vs_pinocchio.sh: Pinocchio's dynamics on a URDF robot,
// over the states file that engine/examples/dynamics_timing.rs reads too.
//
//   pinocchio_timing MODEL.txt STATES.txt values   # JSON: every algorithm's output per state
//   pinocchio_timing MODEL.txt STATES.txt time MS  # JSON: ns per call, best of batches of ~MS ms
//
// STATES.txt: a line `nv count`, then one line per state holding q, qd, qdd, tau.
// Names match the Rust half; forward dynamics comes twice, as the articulated-body
// algorithm (`forward_dynamics_aba`) and as ciflow computes it, CRBA + nonlinear effects +
// sparse Cholesky (`forward_dynamics_cholesky`).

#include "pinocchio/algorithm/aba.hpp"
#include "pinocchio/algorithm/cholesky.hpp"
#include "pinocchio/algorithm/crba.hpp"
#include "pinocchio/algorithm/rnea.hpp"
#include "pinocchio/multibody.hpp"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace
{
  // Timed batches per algorithm; the fastest batch counts (load on a shared machine only
  // ever adds time).
  constexpr int kBatches = 25;

  struct State
  {
    Eigen::VectorXd q, qd, qdd, tau;
  };

  struct Algorithm
  {
    const char * name;
    // Leaves the result in `data`; called through this pointer in the timed loop too, like
    // the Rust half.
    void (*run)(const pinocchio::Model &, pinocchio::Data &, const State &);
    // Row-major output, read outside the timed loop.
    Eigen::VectorXd (*output)(pinocchio::Data &);
  };

  Eigen::VectorXd row_major(const Eigen::MatrixXd & m)
  {
    Eigen::MatrixXd t = m.transpose();
    return Eigen::Map<const Eigen::VectorXd>(t.data(), t.size());
  }

  // Pinocchio's CRBA fills the upper triangle only.
  Eigen::VectorXd symmetric_mass_matrix(pinocchio::Data & data)
  {
    data.M.triangularView<Eigen::StrictlyLower>() =
      data.M.transpose().triangularView<Eigen::StrictlyLower>();
    return row_major(data.M);
  }

  void cholesky_forward_dynamics(
    const pinocchio::Model & model, pinocchio::Data & data, const State & s)
  {
    pinocchio::nonLinearEffects(model, data, s.q, s.qd);
    pinocchio::crba(model, data, s.q);
    pinocchio::cholesky::decompose(model, data);
    data.ddq = s.tau - data.nle;
    pinocchio::cholesky::solve(model, data, data.ddq);
  }

  const std::vector<Algorithm> & algorithms()
  {
    static const std::vector<Algorithm> list = {
      {"rnea",
       [](const pinocchio::Model & model, pinocchio::Data & data, const State & s) {
         pinocchio::rnea(model, data, s.q, s.qd, s.qdd);
       },
       [](pinocchio::Data & data) -> Eigen::VectorXd { return data.tau; }},
      {"crba",
       [](const pinocchio::Model & model, pinocchio::Data & data, const State & s) { pinocchio::crba(model, data, s.q); },
       symmetric_mass_matrix},
      {"gravity",
       [](const pinocchio::Model & model, pinocchio::Data & data, const State & s) {
         pinocchio::computeGeneralizedGravity(model, data, s.q);
       },
       [](pinocchio::Data & data) -> Eigen::VectorXd { return data.g; }},
      {"nonlinear_effects",
       [](const pinocchio::Model & model, pinocchio::Data & data, const State & s) {
         pinocchio::nonLinearEffects(model, data, s.q, s.qd);
       },
       [](pinocchio::Data & data) -> Eigen::VectorXd { return data.nle; }},
      {"coriolis",
       [](const pinocchio::Model & model, pinocchio::Data & data, const State & s) {
         pinocchio::computeCoriolisMatrix(model, data, s.q, s.qd);
       },
       [](pinocchio::Data & data) { return row_major(data.C); }},
      {"forward_dynamics_aba",
       [](const pinocchio::Model & model, pinocchio::Data & data, const State & s) {
         pinocchio::aba(model, data, s.q, s.qd, s.tau);
       },
       [](pinocchio::Data & data) -> Eigen::VectorXd { return data.ddq; }},
      {"forward_dynamics_cholesky", cholesky_forward_dynamics,
       [](pinocchio::Data & data) -> Eigen::VectorXd { return data.ddq; }},
    };
    return list;
  }

  // Rebuilds the model that bench/pinocchio/export_model.py wrote from Pinocchio's URDF parser.
  pinocchio::Model read_model(const std::string & path)
  {
    std::ifstream in(path);
    int joints = 0;
    if (!(in >> joints))
      throw std::runtime_error("model file: joint count expected in " + path);
    pinocchio::Model model;
    for (int j = 1; j <= joints; ++j)
    {
      int parent = 0;
      std::string type;
      Eigen::Vector3d axis, translation, com;
      Eigen::Matrix3d rotation, inertia;
      double mass = 0;
      in >> parent >> type;
      if (type == "RU")
        in >> axis[0] >> axis[1] >> axis[2];
      for (Eigen::Index k = 0; k < 9; ++k)
        in >> rotation(k / 3, k % 3);
      in >> translation[0] >> translation[1] >> translation[2] >> mass;
      in >> com[0] >> com[1] >> com[2];
      for (Eigen::Index k = 0; k < 9; ++k)
        in >> inertia(k / 3, k % 3);
      if (!in)
        throw std::runtime_error("model file: truncated joint line in " + path);
      const pinocchio::SE3 placement(rotation, translation);
      const std::string name = "joint" + std::to_string(j);
      pinocchio::JointIndex id;
      if (type == "RX")
        id = model.addJoint(parent, pinocchio::JointModelRX(), placement, name);
      else if (type == "RY")
        id = model.addJoint(parent, pinocchio::JointModelRY(), placement, name);
      else if (type == "RZ")
        id = model.addJoint(parent, pinocchio::JointModelRZ(), placement, name);
      else if (type == "RU")
        id = model.addJoint(parent, pinocchio::JointModelRevoluteUnaligned(axis), placement, name);
      else
        throw std::runtime_error("model file: unknown joint type " + type);
      model.appendBodyToJoint(id, pinocchio::Inertia(mass, com, inertia));
    }
    return model;
  }

  std::vector<State> read_states(const std::string & path, int nv)
  {
    std::ifstream in(path);
    int file_nv = 0, count = 0;
    if (!(in >> file_nv >> count))
      throw std::runtime_error("states file: header `nv count` expected in " + path);
    if (file_nv != nv)
      throw std::runtime_error("states are for another robot (nv mismatch)");
    std::vector<State> states(count);
    for (State & s : states)
    {
      for (Eigen::VectorXd * v : {&s.q, &s.qd, &s.qdd, &s.tau})
      {
        v->resize(nv);
        for (int i = 0; i < nv; ++i)
          if (!(in >> (*v)[i]))
            throw std::runtime_error("states file: truncated state");
      }
    }
    return states;
  }

  void print_vector(const Eigen::VectorXd & v)
  {
    std::printf("[");
    for (Eigen::Index i = 0; i < v.size(); ++i)
      std::printf("%s%.17g", i ? "," : "", v[i]);
    std::printf("]");
  }

  void values(const pinocchio::Model & model, pinocchio::Data & data, const std::vector<State> & states)
  {
    std::printf("{");
    bool first = true;
    for (const Algorithm & algorithm : algorithms())
    {
      std::printf("%s\"%s\":[", first ? "" : ",", algorithm.name);
      first = false;
      for (std::size_t k = 0; k < states.size(); ++k)
      {
        algorithm.run(model, data, states[k]);
        if (k)
          std::printf(",");
        print_vector(algorithm.output(data));
      }
      std::printf("]");
    }
    std::printf("}\n");
  }

  // Keeps the optimiser from dropping a computation whose result is never read.
  inline void do_not_optimize(pinocchio::Data & data)
  {
    asm volatile("" : : "g"(&data) : "memory");
  }

  // Times `pass` (one call per state) in batches of about batch_ms; the best batch's mean.
  template<typename Pass>
  double best_ns_per_call(Pass && pass, std::size_t calls_per_pass, double batch_ms)
  {
    using clock = std::chrono::steady_clock;
    auto elapsed_ns = [](clock::time_point start) {
      return std::chrono::duration<double, std::nano>(clock::now() - start).count();
    };
    auto start = clock::now();
    pass();
    const double one_pass = std::max(elapsed_ns(start), 1.0);
    const long passes = static_cast<long>(std::ceil(batch_ms * 1e6 / one_pass));
    double best = std::numeric_limits<double>::infinity();
    for (int b = 0; b < kBatches; ++b)
    {
      start = clock::now();
      for (long p = 0; p < passes; ++p)
        pass();
      best = std::min(best, elapsed_ns(start) / double(passes * calls_per_pass));
    }
    return best;
  }

  void time(
    const pinocchio::Model & model,
    pinocchio::Data & data,
    const std::vector<State> & states,
    double batch_ms)
  {
    std::printf("{");
    bool first = true;
    for (const Algorithm & algorithm : algorithms())
    {
      const double ns = best_ns_per_call(
        [&] {
          for (const State & s : states)
          {
            algorithm.run(model, data, s);
            do_not_optimize(data);
          }
        },
        states.size(), batch_ms);
      std::printf("%s\"%s\":%.3f", first ? "" : ",", algorithm.name, ns);
      first = false;
    }
    std::printf("}\n");
  }
} // namespace

int main(int argc, char ** argv)
{
  const std::string usage = "usage: pinocchio_timing MODEL.txt STATES.txt (values | time BATCH_MS)";
  try
  {
    if (argc < 4)
      throw std::runtime_error(usage);
    const pinocchio::Model model = read_model(argv[1]);
    pinocchio::Data data(model);
    const std::vector<State> states = read_states(argv[2], model.nv);
    const std::string mode = argv[3];
    if (mode == "values" && argc == 4)
      values(model, data, states);
    else if (mode == "time" && argc == 5)
      time(model, data, states, std::stod(argv[4]));
    else
      throw std::runtime_error(usage);
  }
  catch (const std::exception & e)
  {
    std::cerr << "pinocchio_timing: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
