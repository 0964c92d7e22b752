// A C interface to nav2_amcl's particle filter, as nav2's amcl_node drives it: the likelihood
// field (or beam) model on an occupancy grid, the differential (or omni) motion model, resampling
// on every update, global localization from the map's free cells, and the pose of the heaviest
// cluster. Compiled with nav2_amcl's own sources by `python -m fusion.bench.nav2_amcl`; loaded
// with ctypes by fusion/bench/nav2_amcl/filter.py. Every function returns 0 on success.

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <vector>

#include "nav2_amcl/map/map.hpp"
#include "nav2_amcl/motion_model/differential_motion_model.hpp"
#include "nav2_amcl/motion_model/omni_motion_model.hpp"
#include "nav2_amcl/pf/pf.hpp"
#include "nav2_amcl/pf/pf_pdf.hpp"
#include "nav2_amcl/sensors/laser/laser.hpp"

namespace {

struct Filter {
  pf_t * pf = nullptr;
  map_t * map = nullptr;
  std::unique_ptr<nav2_amcl::MotionModel> motion;
  std::unique_ptr<nav2_amcl::Laser> laser;
  std::vector<int> free_cells;  // MAP_INDEX of every free cell: where global poses are drawn
  pf_vector_t odom_at_update{};
  bool has_odom = false;
  int resample_count = 0;
  int resample_interval = 1;
  long seed = 0;

  ~Filter() {
    laser.reset();
    if (pf != nullptr) {pf_free(pf);}
    if (map != nullptr) {map_free(map);}
  }
};

// nav2's uniform pose generator: a free cell at random, a heading at random.
pf_vector_t uniform_free_pose(void * data) {
  auto * f = static_cast<Filter *>(data);
  pf_vector_t p = pf_vector_zero();
  if (f->free_cells.empty()) {return p;}
  int k = f->free_cells[static_cast<size_t>(drand48() * f->free_cells.size())
                        % f->free_cells.size()];
  int i = k % f->map->size_x, j = k / f->map->size_x;
  p.v[0] = MAP_WXGX(f->map, i);
  p.v[1] = MAP_WYGY(f->map, j);
  p.v[2] = drand48() * 2 * M_PI - M_PI;
  return p;
}

// A sample of the Gaussian: what pf_init draws each particle from.
pf_vector_t gaussian_pose(void * pdf) {
  return pf_pdf_gaussian_sample(static_cast<pf_pdf_gaussian_t *>(pdf));
}

}  // namespace

extern "C" {

void * hl_amcl_new(int min_particles, int max_particles, double alpha_slow, double alpha_fast,
                   double pf_err, double pf_z, const double * alpha, int omni,
                   int resample_interval, long seed) {
  auto * f = new Filter();
  f->pf = pf_alloc(min_particles, max_particles, alpha_slow, alpha_fast, uniform_free_pose);
  f->pf->pop_err = pf_err;
  f->pf->pop_z = pf_z;
  f->seed = seed;
  srand48(seed);  // pf_alloc seeded from the clock; a benchmark repeats
  if (omni) {
    f->motion = std::make_unique<nav2_amcl::OmniMotionModel>();
  } else {
    f->motion = std::make_unique<nav2_amcl::DifferentialMotionModel>();
  }
  f->motion->initialize(alpha[0], alpha[1], alpha[2], alpha[3], alpha[4]);
  f->resample_interval = resample_interval < 1 ? 1 : resample_interval;
  return f;
}

void hl_amcl_free(void * handle) {delete static_cast<Filter *>(handle);}

// The grid as nav_msgs/OccupancyGrid has it (row-major, x fastest; 0 free, 100 occupied, else
// unknown), and the sensor model: 0 likelihood field, 1 beam. params: z_hit, z_short, z_max,
// z_rand, sigma_hit, lambda_short, chi_outlier, laser_likelihood_max_dist.
int hl_amcl_set_map(void * handle, int size_x, int size_y, double resolution, double origin_x,
                    double origin_y, const int8_t * data, int beam, const double * params,
                    int max_beams) {
  auto * f = static_cast<Filter *>(handle);
  f->laser.reset();
  if (f->map != nullptr) {map_free(f->map);}
  map_t * map = map_alloc();
  map->size_x = size_x;
  map->size_y = size_y;
  map->scale = resolution;
  map->origin_x = origin_x + (size_x / 2) * resolution;
  map->origin_y = origin_y + (size_y / 2) * resolution;
  map->cells = static_cast<map_cell_t *>(malloc(sizeof(map_cell_t) * size_x * size_y));
  if (map->cells == nullptr) {map_free(map); f->map = nullptr; return 1;}
  f->free_cells.clear();
  for (int k = 0; k < size_x * size_y; k++) {
    map->cells[k].occ_state = data[k] == 0 ? -1 : (data[k] == 100 ? +1 : 0);
    if (data[k] == 0) {f->free_cells.push_back(k);}
  }
  f->map = map;
  if (beam) {
    f->laser = std::make_unique<nav2_amcl::BeamModel>(
      params[0], params[1], params[2], params[3], params[4], params[5], params[6],
      static_cast<size_t>(max_beams), map);
  } else {
    f->laser = std::make_unique<nav2_amcl::LikelihoodFieldModel>(
      params[0], params[3], params[4], params[7], static_cast<size_t>(max_beams), map);
  }
  return 0;
}

int hl_amcl_set_laser_pose(void * handle, double x, double y, double yaw) {
  auto * f = static_cast<Filter *>(handle);
  if (!f->laser) {return 1;}
  pf_vector_t p = pf_vector_zero();
  p.v[0] = x; p.v[1] = y; p.v[2] = yaw;
  f->laser->SetLaserPose(p);
  return 0;
}

// cov: 3×3 row-major. As nav2's handleInitialPose: the next update only takes the odometry.
int hl_amcl_init_pose(void * handle, const double * mean, const double * cov) {
  auto * f = static_cast<Filter *>(handle);
  pf_vector_t m = pf_vector_zero();
  pf_matrix_t c = pf_matrix_zero();
  for (int i = 0; i < 3; i++) {
    m.v[i] = mean[i];
    for (int j = 0; j < 3; j++) {c.m[i][j] = cov[3 * i + j];}
  }
  // pf_init's samples, drawn after the seed: allocating the Gaussian reseeds drand48 from a
  // count of every Gaussian the process made, which would make a run depend on the ones before
  pf_pdf_gaussian_t * pdf = pf_pdf_gaussian_alloc(m, c);
  srand48(f->seed);
  pf_init_model(f->pf, gaussian_pose, pdf);
  pf_pdf_gaussian_free(pdf);
  f->has_odom = false;
  return 0;
}

// nav2's reinitialize_global_localization: particles over the map's free cells.
int hl_amcl_init_global(void * handle) {
  auto * f = static_cast<Filter *>(handle);
  if (f->map == nullptr || f->free_cells.empty()) {return 1;}
  srand48(f->seed);
  pf_init_model(f->pf, uniform_free_pose, f);
  f->has_odom = false;
  return 0;
}

// Motion to the odometry pose, the scan's weights, then resampling every resample_interval
// updates, as nav2's laserReceived once the robot moved enough. ranges: n (range, bearing)
// pairs, bearing in the laser's frame; a range at or beyond range_max is ignored.
int hl_amcl_update(void * handle, const double * odom, int n, const double * ranges,
                   double range_max) {
  auto * f = static_cast<Filter *>(handle);
  if (!f->laser) {return 1;}
  pf_vector_t pose = pf_vector_zero();
  pose.v[0] = odom[0]; pose.v[1] = odom[1]; pose.v[2] = odom[2];
  if (!f->has_odom) {
    f->odom_at_update = pose;
    f->has_odom = true;
  }
  pf_vector_t delta = pf_vector_zero();
  delta.v[0] = pose.v[0] - f->odom_at_update.v[0];
  delta.v[1] = pose.v[1] - f->odom_at_update.v[1];
  delta.v[2] = std::atan2(std::sin(pose.v[2] - f->odom_at_update.v[2]),
                          std::cos(pose.v[2] - f->odom_at_update.v[2]));
  f->motion->odometryUpdate(f->pf, pose, delta);

  nav2_amcl::LaserData data;
  data.laser = f->laser.get();
  data.range_count = n;
  data.range_max = range_max;
  data.ranges = new double[n][2];  // LaserData's destructor deletes it
  for (int i = 0; i < n; i++) {
    data.ranges[i][0] = ranges[2 * i];
    data.ranges[i][1] = ranges[2 * i + 1];
  }
  f->laser->sensorUpdate(f->pf, &data);
  f->odom_at_update = pose;
  if (++f->resample_count % f->resample_interval == 0) {
    pf_update_resample(f->pf, f);
  }
  return 0;
}

// What nav2 publishes as amcl_pose: the mean of the heaviest cluster, and the covariance of
// the whole sample set (row-major 3×3). Returns 1 when no cluster has weight.
int hl_amcl_estimate(void * handle, double * mean, double * cov) {
  auto * f = static_cast<Filter *>(handle);
  pf_sample_set_t * set = f->pf->sets + f->pf->current_set;
  double best = 0.0;
  pf_vector_t best_mean = pf_vector_zero();
  for (int k = 0; k < set->cluster_count; k++) {
    double weight;
    pf_vector_t m;
    pf_matrix_t c;
    if (!pf_get_cluster_stats(f->pf, k, &weight, &m, &c)) {break;}
    if (weight > best) {best = weight; best_mean = m;}
  }
  for (int i = 0; i < 3; i++) {
    mean[i] = best_mean.v[i];
    for (int j = 0; j < 3; j++) {cov[3 * i + j] = set->cov.m[i][j];}
  }
  return best > 0.0 ? 0 : 1;
}

// The current samples as (x, y, yaw, weight) rows, at most `capacity`; returns their count.
int hl_amcl_particles(void * handle, double * out, int capacity) {
  auto * f = static_cast<Filter *>(handle);
  pf_sample_set_t * set = f->pf->sets + f->pf->current_set;
  int n = set->sample_count < capacity ? set->sample_count : capacity;
  for (int k = 0; k < n; k++) {
    const pf_sample_t & s = set->samples[k];
    out[4 * k] = s.pose.v[0];
    out[4 * k + 1] = s.pose.v[1];
    out[4 * k + 2] = s.pose.v[2];
    out[4 * k + 3] = s.weight;
  }
  return n;
}

}  // extern "C"
