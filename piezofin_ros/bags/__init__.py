"""Messages and recordings, free of ROS: the self-describing block layout of every topic
(:mod:`.blocks`) and MCAP files as rosbag2 writes and reads them (:mod:`.mcapio`: writer,
tolerant reader, recovery, CDR), readable without a ROS installation.
"""
