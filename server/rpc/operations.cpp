// GetOperation, WatchOperation, CancelOperation, ListOperations: the build queue's operations and the index's rows.
#include <algorithm>

#include "convert.h"
#include "service.h"

namespace posewarp::server {

grpc::Status PosewarpService::GetOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                                           v1::Operation* response) {
  Call call(frame_, context, "GetOperation");
  if (call.refused()) return call.refusal();
  Result<v1::Operation> operation = builds_.find(request->operation_id());
  if (!operation.ok()) return call.done(operation.status());
  *response = std::move(operation).value();
  return call.done(ok_status());
}

grpc::Status PosewarpService::WatchOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                                             grpc::ServerWriter<v1::Operation>* writer) {
  Call call(frame_, context, "WatchOperation");
  if (call.refused()) return call.refusal();
  return call.done(builds_.watch(
      request->operation_id(), [&](const v1::Operation& operation) { return call.write(writer, operation); },
      [context] { return context->IsCancelled(); }));
}

grpc::Status PosewarpService::CancelOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                                              v1::Operation* response) {
  Call call(frame_, context, "CancelOperation");
  if (call.refused()) return call.refusal();
  Result<v1::Operation> operation = builds_.cancel(request->operation_id());
  if (!operation.ok()) return call.done(operation.status());
  *response = std::move(operation).value();
  return call.done(ok_status());
}

grpc::Status PosewarpService::ListOperations(grpc::ServerContext* context, const v1::ListOperationsRequest* request,
                                             v1::ListOperationsResponse* response) {
  Call call(frame_, context, "ListOperations");
  if (call.refused()) return call.refusal();
  const int page = request->page_size() <= 0 ? 50 : std::min(request->page_size(), 1000);
  Result<std::vector<OperationRecord>> rows = store_->index().operations(request->page_token(), page + 1);
  if (!rows.ok()) return call.done(rows.status());
  for (const OperationRecord& row : *rows) {
    if (response->operations_size() == page) {
      response->set_next_page_token(response->operations(page - 1).id());
      break;
    }
    // A live build shows its progress; the index has its state transitions.
    Result<v1::Operation> live = builds_.find(row.id);
    *response->add_operations() = live.ok() ? *live : operation_from(row);
  }
  return call.done(ok_status());
}

}  // namespace posewarp::server
