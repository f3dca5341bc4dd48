"""What every service is built on: the service runtime, its single writer, health, jobs and uploads."""
